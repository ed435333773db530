"""Contact fusion service: integrator + condensation + event tracker behind one Module shell.

Its ``hypotheses`` input is bound to a key expression over generator clouds, e.g. every
generator of every robot of the site (``KeySpace.hypotheses("*", "*")``); each
``robot/generator`` pair is a source, plugged on its first cloud and unplugged after
``drop_after`` seconds of silence. Each cycle publishes the fused cloud, the condensed
contacts, the contact events and, with a ``map_region``, the object map on ``KeySpace.fused(robot, stream)`` (see
:meth:`ContactFusion.default_output_keys`) and raises the events for the task engine.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.messages import RobotModel
from contactflow.fusion.condensation import CondensationParams, Method
from contactflow.fusion.events import ContactTracker, TrackerParams
from contactflow.fusion.generators.base import capsules_of
from contactflow.fusion.hypotheses import VOXEL_SIZE, Hypotheses
from contactflow.fusion.integrator import Integrator, IntegratorParams
from contactflow.fusion.loop import FusionLoop
from contactflow.fusion.messages import (
    ContactEventMsg,
    ContactInfo,
    ContactList,
    FusedCloud,
    HypothesisCloud,
    MapClaim,
    MappedObjectInfo,
    ObjectMapMsg,
)
from contactflow.fusion.object_map import ObjectMap, ObjectMapParams
from contactflow.fusion.regions import RegionParams, classify
from contactflow.nodes.keys import ANY, KeySpace
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import WireError
from contactflow.recognition import open3d_backend


@dataclass(frozen=True)
class FusionParams:
    rate_hz: float = 200.0  # Hz, how often the integrator checks for a complete cycle
    robot: str = "site"  # robot segment of the fused keys ("site" for a shared integrator)
    sources: str = "*/*"  # robot/generator pattern of the clouds to fuse
    generators: tuple[str, ...] = ()  # of those, only the clouds of these generators (e.g. a modality's); (): all
    voxel_size: float = VOXEL_SIZE  # m
    timeout: float = 0.5  # s, hypothesis lifetime
    wait_timeout: float = 0.25  # s, longest wait for a late source
    source_timeout: float = 2.0  # s, silence after which a source is not waited for
    drop_after: float = 10.0  # s, silence after which a source is unplugged
    method: Method = Method.CLUSTER
    threshold: float = 0.02  # absolute floor on H(x)
    relative_threshold: float = 0.1  # floor as a fraction of the cycle's largest H(x)
    cluster_eps: float = 0.012  # m
    min_mass: float = 0.3  # likelihood sum that makes a cluster a contact
    match_radius: float = 0.03  # m, event tracker association distance
    confirm: int = 1  # cycles before a contact is made
    hold: float = 0.1  # s, unseen time before a contact is broken
    publish_hypotheses: bool = True
    region_margin: float = 0.015  # m, a contact this close to a hand link of the robot's posed model lies on it (fusion.regions)
    region_reach: float = 0.12  # m, farther out but this close to the hand: on what the hand holds
    map_region: tuple[float, ...] = ()  # m, world box [xmin, ymin, zmin, xmax, ymax, zmax]: map what the contacts touch in it (objects output); (): no map
    map_merge: float = 0.04  # m, a contact this close to a mapped object is on it
    map_memory: int = 8  # a mapped object moves 1/min(sightings, map_memory) of the way to each sighting (a carried one is followed)

    def validate(self) -> None:
        parts = self.sources.split("/")
        if len(parts) != 2 or not all(parts):
            raise ValueError(f"sources={self.sources!r} must be '<robot>/<generator>' (either may be '*')")
        if self.generators and parts[1] != "*":
            raise ValueError(f"generators={list(self.generators)}: give them with sources '<robot>/*', "
                             f"not {self.sources!r}")
        self.integrator().validate()
        self.condensation().validate()
        self.tracker().validate()
        self.regions().validate()
        self.object_map().validate()

    def object_map(self) -> ObjectMapParams:
        return ObjectMapParams(self.map_region, self.map_merge, self.map_memory)

    def regions(self) -> RegionParams:
        return RegionParams(self.region_margin, self.region_reach)

    def integrator(self) -> IntegratorParams:
        return IntegratorParams(self.voxel_size, self.timeout, self.wait_timeout, self.source_timeout)

    def condensation(self) -> CondensationParams:
        return CondensationParams(self.method, self.threshold, self.relative_threshold, self.cluster_eps, 1,
                                  self.min_mass)

    def tracker(self) -> TrackerParams:
        return TrackerParams(self.match_radius, self.confirm, self.hold)


class ContactFusion(Module):
    """Fuses contact hypothesis clouds into contacts and contact events (thesis §4.6)."""

    layer = Layer.SERVICE
    Params = FusionParams
    inputs = (Port("hypotheses", HypothesisCloud, "clouds of any set of generators, world frame"),
              Port("robot_model", RobotModel, "the robot's posed model: where on the hand each contact lies (optional)"),
              Port("claims", MapClaim, "robots going for an object of the map (with map_region)"))
    outputs = (
        Port("hypotheses", FusedCloud, "fused hypotheses H(x)"),
        Port("contacts", ContactList, "condensed contacts"),
        Port("events", ContactEventMsg, "contact made / broken"),
        Port("objects", ObjectMapMsg, "the objects the contacts touched in map_region"),
    )
    events = (Event.CONTACT_MADE, Event.CONTACT_BROKEN)

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: FusionParams) -> dict[str, str]:
        robot, generator = params.sources.split("/")
        keys = {"hypotheses": ks.hypotheses(robot, generator)}
        if params.map_region:  # a fusion without an object map has no claims to count: it does not hear them
            keys["claims"] = ks.fused(ANY, "claims")
        return keys

    @classmethod
    def default_output_keys(cls, ks: KeySpace, robot: str, name: str, params: FusionParams) -> dict[str, str]:
        return {stream: ks.fused(params.robot, stream) for stream in ("hypotheses", "contacts", "events", "objects")}

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        self.params.validate()
        # the clustering's library loads now: in the first cycle its import would hold the loop while clouds queue
        open3d_backend.load()
        self.reset()

    def reset(self) -> None:
        p = self.params
        self.loop = FusionLoop(p.integrator(), p.condensation(), p.tracker(), drop_after=p.drop_after)
        self.rejected = 0
        self.objects = ObjectMap(p.object_map()) if p.map_region else None
        self._model_msg: object = None  # the RobotModel last read, and its (robot, bi-spheres, links, regions)
        self._model: tuple[str, np.ndarray, list[str], list[str]] | None = None

    @property
    def integrator(self) -> Integrator:
        return self.loop.integrator

    @property
    def tracker(self) -> ContactTracker:
        return self.loop.tracker

    def on_params(self, old) -> None:  # type: ignore[no-untyped-def]
        p = self.params
        p.validate()
        self.loop.drop_after = p.drop_after
        self.loop.retune(p.integrator(), p.condensation(), p.tracker())
        if p.object_map() != old.object_map():
            self.objects = ObjectMap(p.object_map()) if p.map_region else None

    def admit(self, msg: HypothesisCloud, now: float) -> Hypotheses | None:
        """The cloud of ``msg`` for the next cycle (None: not fused); a malformed cloud raises WireError."""
        return msg.hypotheses()

    def step(self) -> Status:
        assert self.io is not None
        now = self.io.now
        only = self.params.generators
        self._claims()
        for msg in self.io.take("hypotheses"):
            assert isinstance(msg, HypothesisCloud)
            if only and msg.generator not in only:
                continue
            try:
                cloud = self.admit(msg, now)
            except WireError as exc:
                self.rejected += 1
                self.io.log(f"rejected cloud: {exc}")
                continue
            if cloud is not None:
                self.loop.offer(msg.source, cloud, now, robot=msg.robot, link=msg.link, msg=msg.hdr.id)
        cycle = self.loop.step(now)
        if cycle is None:
            return Status.RUNNING
        fused, contacts = cycle.fused, cycle.contacts
        if self.params.publish_hypotheses:
            self.io.publish("hypotheses", FusedCloud.of(fused))
        where = self._regions([c.location for c in contacts] + [e.location for e in cycle.events],
                              [c.robot for c in contacts] + [e.robot for e in cycle.events],
                              [c.sigma for c in contacts] + [e.sigma for e in cycle.events])
        self.io.publish("contacts", ContactList(stamp=now, contacts=[ContactInfo.of(c, fused.columns, r)
                                                                     for c, r in zip(contacts, where[:len(contacts)], strict=True)]),
                        inputs=self.loop.inputs(fused.columns))
        for e, (region, part) in zip(cycle.events, where[len(contacts):], strict=True):
            self.io.publish("events", ContactEventMsg.of(e, (region, part)), inputs=self.loop.inputs(e.sources))
            x, y, z = (float(v) for v in np.asarray(e.location))
            on = f"{e.robot}/{e.link}" if e.link else e.robot
            self.io.emit(e.event, f"{on} {region} ({part})" if region else on,
                         {"id": float(e.id), "x": x, "y": y, "z": z, "likelihood": float(e.likelihood)})
        if self.objects is not None:
            self.objects.touch([c.location for c in contacts], [c.robot for c in contacts], now)
            self.io.publish("objects", ObjectMapMsg(map=self.params.robot, stamp=now, objects=[MappedObjectInfo.of(o) for o in self.objects.objects]))
        return Status.RUNNING

    def _claims(self) -> None:
        """Count the robots' claims on the objects of this map (claims on other maps are dropped; without a map none come)."""
        assert self.io is not None
        for msg in self.io.take("claims"):
            if self.objects is None or not isinstance(msg, MapClaim) or msg.map != self.params.robot:
                continue
            if not self.objects.claim(msg.object_id):
                self.io.log(f"{msg.robot} claimed object {msg.object_id}, which the map does not hold")

    def _regions(self, locations: list[np.ndarray], robots: list[str], spread: list[float]) -> list[tuple[str, str]]:
        """Where on the hand each contact (location, robot, spread in m) lies, by the latest posed model. Untold,
        ``("", "")``: no model bound or heard, a model of another robot, one naming no hand parts, or a malformed
        one (the first of a run of those is logged)."""
        assert self.io is not None
        untold = [("", "")] * len(locations)
        model = self.io.latest("robot_model")
        if model is None or not locations or (isinstance(model, RobotModel) and not model.regions):
            return untold
        if model is not self._model_msg:
            told_bad = self._model_msg is not None and self._model is None
            self._model_msg, self._model = model, None
            try:
                caps = capsules_of(model, "robot_model", self.name)
                if len(model.regions) != len(model.links):
                    raise ValueError(f"{self.name}: input 'robot_model' ({model.robot}): {len(model.regions)} "
                                     f"regions for {len(model.links)} links")
                self._model = (model.robot, caps, list(model.links), list(model.regions))
            except (TypeError, ValueError) as exc:
                if not told_bad:
                    self.io.log(f"no contact regions: {exc}")
        if self._model is None:
            return untold
        robot, caps, links, regions = self._model
        mine = [k for k, r in enumerate(robots) if r == robot]
        if not mine:
            return untold
        told = classify(np.array([locations[k] for k in mine]), caps, links, regions, self.params.regions(),
                        np.array([spread[k] for k in mine]))
        for k, r in zip(mine, told, strict=True):
            untold[k] = r
        return untold
