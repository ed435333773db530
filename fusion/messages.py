"""Wire messages of contact fusion: hypothesis clouds, fused clouds, contacts, contact events, object maps.

Arrays travel as :class:`~contactflow.nodes.wire.NDArray` in float32 (5 mm voxels need no
more) except time stamps and bitmasks. Every location is in the one world frame.
"""

from __future__ import annotations

import msgspec
import numpy as np

from contactflow.fusion.condensation import Contact
from contactflow.fusion.events import ContactEvent
from contactflow.fusion.hypotheses import Hypotheses, HypothesisType
from contactflow.fusion.integrator import Fused
from contactflow.fusion.object_map import MappedObject
from contactflow.nodes.status import Event
from contactflow.nodes.wire import Message, NDArray, WireError


def nd(a: np.ndarray) -> NDArray:
    """``NDArray.of`` that also accepts arrays with a zero-length dimension."""
    if a.size == 0:
        return NDArray(dtype=np.dtype(a.dtype).name, shape=list(a.shape), data=memoryview(b""))
    return NDArray.of(a)


def _arr(msg_name: str, field: str, a: NDArray, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    out = a.numpy()
    if out.shape != shape:
        raise WireError(f"{msg_name}.{field}: shape {tuple(out.shape)}, expected {shape}")
    return out.astype(dtype, copy=False)


class HypothesisCloud(Message, tag="hypothesis_cloud"):
    """One generator's cloud (thesis §4.2.1), published on ``KeySpace.hypotheses(robot, generator)``.

    ``robot`` is the robot whose contacts the cloud is about (a head camera of robot A may
    publish about robot B), ``link`` the link the hypotheses lie on when the generator knows
    it. ``stamp`` is the time of the sensor reading. ``force`` and ``direction`` may be empty
    arrays when the generator knows no force.
    """

    max_bytes = 64 << 20
    robot: str
    generator: str  # the generator's name (tactile, ft, range, ...)
    stamp: float  # s, time of the sensor reading
    location: NDArray  # (n, 3) float32, m, world frame
    likelihood: NDArray  # (n,) float32 in [0, 1]
    kind: NDArray  # (n,) uint8 HypothesisType
    force: NDArray  # (n,) float32 N, or (0,)
    direction: NDArray  # (n, 3) float32 unit, or (0, 3)
    link: str = ""  # the link the hypotheses lie on, when the generator knows it
    frame: str = "world"  # always world: fusion works in one frame

    @property
    def source(self) -> str:
        return f"{self.robot}/{self.generator}"

    @classmethod
    def of(cls, h: Hypotheses, robot: str, generator: str, link: str = "") -> HypothesisCloud:
        has_force = bool(len(h)) and bool(np.any(h.force) or np.any(h.direction))
        return cls(
            robot=robot, generator=generator, stamp=h.stamp, link=link,
            location=nd(h.location.astype(np.float32)),
            likelihood=nd(h.likelihood.astype(np.float32)),
            kind=nd(h.kind.astype(np.uint8)),
            force=nd(h.force.astype(np.float32) if has_force else np.zeros(0, np.float32)),
            direction=nd(h.direction.astype(np.float32) if has_force else np.zeros((0, 3), np.float32)),
        )

    def hypotheses(self) -> Hypotheses:
        """Decode into a validated :class:`Hypotheses` (errors name the message and field)."""
        where = f"HypothesisCloud({self.source})"
        if self.frame != "world":
            raise WireError(f"{where}.frame: {self.frame!r}, fusion works in the world frame")
        loc = self.location.numpy()
        if loc.ndim != 2 or loc.shape[1] != 3:
            raise WireError(f"{where}.location: shape {tuple(loc.shape)}, expected (n, 3)")
        n = loc.shape[0]
        lik = _arr(where, "likelihood", self.likelihood, (n,), np.float64)
        kind = _arr(where, "kind", self.kind, (n,), np.uint8)
        if self.force.shape == [0]:
            force = np.zeros(n)
        else:
            force = _arr(where, "force", self.force, (n,), np.float64)
        if self.direction.shape == [0, 3]:
            direction = np.zeros((n, 3))
        else:
            direction = _arr(where, "direction", self.direction, (n, 3), np.float64)
        h = Hypotheses(loc.astype(np.float64), lik, kind, force, direction, float(self.stamp))
        try:
            h.validate(where)
        except ValueError as exc:
            raise WireError(str(exc)) from None
        return h


class FusedCloud(Message, tag="fused_cloud"):
    """The fused hypotheses H(x) of one integrator cycle (for display and analysis)."""

    max_bytes = 64 << 20
    stamp: float  # s, time of the cycle
    location: NDArray  # (k, 3) float32
    likelihood: NDArray  # (k,) float32
    force: NDArray  # (k,) float32
    direction: NDArray  # (k, 3) float32
    sources: NDArray  # (k,) uint64 bitmask over ``columns``
    columns: list[str]  # the sources (robot/generator) of the cycle, one bit each
    vetoed: int = 0  # voxels removed by null hypotheses this cycle
    unsupported: int = 0  # voxels with support hypotheses only, left out this cycle

    @classmethod
    def of(cls, f: Fused) -> FusedCloud:
        return cls(
            stamp=f.stamp, location=nd(f.location.astype(np.float32)),
            likelihood=nd(f.likelihood.astype(np.float32)), force=nd(f.force.astype(np.float32)),
            direction=nd(f.direction.astype(np.float32)), sources=nd(f.sources.astype(np.uint64)),
            columns=list(f.columns), vetoed=f.vetoed, unsupported=f.unsupported,
        )


class ContactInfo(msgspec.Struct, frozen=True, kw_only=True):
    """One condensed contact."""

    location: list[float]  # m, world frame
    likelihood: float  # in [0, 1]
    sigma: float  # m
    force: float  # N
    direction: list[float]  # unit, world
    voxels: int  # voxels condensed into it
    sources: list[str]  # the sources (robot/generator) behind it
    robot: str = ""  # the robot it touches
    link: str = ""  # the link it lies on, when known (the hand a hand's cues name)
    region: str = ""  # where on the hand: finger | palm | held_object ("": not told, no posed model of the robot)
    part: str = ""  # the hand link nearest to it, with a region

    @classmethod
    def of(cls, c: Contact, columns: list[str], region: tuple[str, str] = ("", "")) -> ContactInfo:
        names = [n for i, n in enumerate(columns) if n and (c.sources >> i) & 1]
        return cls(location=[float(v) for v in c.location], likelihood=c.likelihood, sigma=c.sigma, force=c.force,
                   direction=[float(v) for v in c.direction], voxels=c.voxels, sources=names, robot=c.robot,
                   link=c.link, region=region[0], part=region[1])


class ContactList(Message, tag="contact_list"):
    """The condensed contacts of one cycle, on ``KeySpace.fused(robot, "contacts")``."""

    stamp: float  # s, time of the cycle
    contacts: list[ContactInfo] = []  # the contacts


class ContactEventMsg(Message, tag="contact_event"):
    """A contact made or broken, on ``KeySpace.fused(robot, "events")``."""

    event: Event  # contact_made or contact_broken
    contact_id: int  # the tracked contact's id (the same for its made and broken)
    robot: str
    link: str  # the link it lies on, when known
    location: list[float]  # m, world frame
    likelihood: float  # in [0, 1]
    t: float  # s, when it was made or broken
    sources: list[str] = []  # the sources (robot/generator) behind the contact; hdr.inputs names their clouds
    region: str = ""  # where on the hand: finger | palm | held_object ("": not told)
    part: str = ""  # the hand link nearest to it, with a region

    def __post_init__(self) -> None:
        if self.event not in (Event.CONTACT_MADE, Event.CONTACT_BROKEN):
            raise ValueError(f"ContactEventMsg.event: {self.event!r} is not contact_made or contact_broken")

    @classmethod
    def of(cls, e: ContactEvent, region: tuple[str, str] = ("", "")) -> ContactEventMsg:
        return cls(event=e.event, contact_id=e.id, robot=e.robot, link=e.link,
                   location=[float(v) for v in e.location], likelihood=e.likelihood, t=e.t, sources=list(e.sources),
                   region=region[0], part=region[1])


class MappedObjectInfo(msgspec.Struct, frozen=True, kw_only=True):
    """One object of an object map: where the contacts that touched it place it."""

    id: int  # the map's id of the object (kept while it is mapped)
    location: list[float]  # m, world frame: the mean of its last sightings
    sightings: int  # fusion cycles in which a contact lay on it
    touched: dict[str, float]  # robot -> s, when that robot last touched it
    claims: int  # claims since it was last touched (hands that went for it and found nothing)

    @classmethod
    def of(cls, o: MappedObject) -> MappedObjectInfo:
        return cls(id=o.id, location=[float(v) for v in o.location], sightings=o.sightings, touched=dict(o.touched),
                   claims=o.claims)


class ObjectMapMsg(Message, tag="object_map"):
    """The objects a fusion's contacts touched in its map region, on ``KeySpace.fused(robot, "objects")``."""

    map: str  # the map's name: its fusion's robot param (a robot's, or a cell's)
    stamp: float  # s, time of the cycle
    objects: list[MappedObjectInfo] = []  # the mapped objects


class MapClaim(Message, tag="map_claim"):
    """A robot goes for an object of a map, on ``KeySpace.fused(robot, "claims")`` (the map of that name counts it)."""

    map: str  # the map's name (its ObjectMapMsg's)
    robot: str  # the robot that goes for it
    object_id: int  # the object's id in the map
    location: list[float]  # m, world frame: where the robot goes


__all__ = ["ContactEventMsg", "ContactInfo", "ContactList", "FusedCloud", "HypothesisCloud", "HypothesisType",
           "MapClaim", "MappedObjectInfo", "ObjectMapMsg"]
