"""A robot station's own contact fusion: its tactile and wrist F/T cues fused into contact events.

Runs beside the simulated robot at a fixed rate (thesis: fusion cycles at ~6-30 Hz): each
hand's pads and each arm's wrist sensor are sources of the one fusion loop (``fusion/loop.py``, as in the
fusion service): its contact events (``contact_made``/``contact_broken``) are what the
station publishes on ``contacts/fused/<robot>/events``. Every cycle each source's hypothesis
cloud (empty when it feels nothing) also goes out on ``contacts/<robot>/<generator>``
(generators ``tactile_<arm>``, ``force_torque_<arm>``), so ``contactflow echo`` and other
robots' integrators see them; :func:`cloud_publisher` sends them over a transport.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from contactflow.fusion.condensation import CondensationParams
from contactflow.fusion.events import ContactEvent, TrackerParams
from contactflow.fusion.generators.tactile import tactile_hypotheses
from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.integrator import IntegratorParams
from contactflow.fusion.loop import FusionLoop
from contactflow.fusion.messages import HypothesisCloud
from contactflow.fusion.sim_sources import hand_capsules, taxel_readings, wrist_hypotheses
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.transport import Transport
from contactflow.nodes.wire import MsgId, encode, stamp

CloudSink = Callable[[str, HypothesisCloud, list[MsgId]], MsgId]
"""Sends (key expression, cloud, the sensor messages it came from) for every generator cloud of a
cycle; returns the id the cloud went out with."""


def cloud_publisher(transport: Transport, source: str) -> CloudSink:
    """A :data:`CloudSink` publishing each cloud on its key, stamped with ``source`` and the cloud's time."""
    pubs: dict[str, Callable[[bytes], None]] = {}
    seqs: dict[str, int] = {}  # per key: each stream numbers its own messages, so gaps mean loss

    def send(key: str, cloud: HypothesisCloud, inputs: list[MsgId]) -> MsgId:
        if key not in pubs:
            pubs[key] = transport.publisher(key)
        seqs[key] = seqs.get(key, 0) + 1
        pubs[key](encode(stamp(cloud, f"{source}/{cloud.generator}", seqs[key], cloud.stamp, inputs)))
        return cloud.hdr.id

    return send


@dataclass(frozen=True)
class StationParams:
    rate_hz: float = 20.0  # Hz, fusion cycles
    min_force: float = 1.5  # N, wrist forces below this feed no F/T source (noise, own weight)
    hold: float = 0.3  # s, a contact unseen this long is broken


@dataclass
class Cue:
    """One arm's contact cues: its hand's pads and its wrist F/T."""

    name: str
    arm: str
    hand: str
    ft_link: str
    links: tuple[str, ...]
    min_force: float  # N, below this the wrist reading is noise


def robot_cues(robot: object, min_force: float) -> list[Cue]:
    """The cues of every arm of ``robot`` with a hand (a SimRobot, or a world's robot over the key space)."""
    spec = robot.spec
    cues = []
    for arm in spec.arms:
        if not arm.hand:
            continue
        hand = spec.hand(arm.hand)
        ft = spec.ft(arm.ft) if arm.ft else None
        ft_link = ft.link if ft is not None else ""
        prefixes = tuple(p for p in (hand.palm_link, *hand.fingertips) if p) or (ft_link,)
        # 4 sigma above the sensor noise: an estimated wrench (Baxter) is far noisier
        floor = max(min_force, 4.0 * ft.force_noise) if ft is not None else min_force
        cues.append(Cue(arm.name, arm.name, hand.name, ft_link, prefixes, floor))
    return cues


def cue_clouds(robot: object, cue: Cue, now: float) -> list[tuple[str, Hypotheses]]:
    """``(generator, cloud)`` of the cue's pads (``tactile_<arm>``) and wrist F/T (``force_torque_<arm>``) now;
    a cloud is empty when its sensor feels nothing."""
    pressure, taxels, normals = taxel_readings(robot, cue.hand)
    cloud = Hypotheses.empty(now)
    if pressure.size and float(pressure.max()) > 0:
        cloud = tactile_hypotheses(pressure, taxels, now, normals)
    out = [(f"tactile_{cue.name}", cloud)]
    if cue.ft_link:
        force = np.linalg.norm(robot.ft(cue.arm).in_sensor_frame()[0])
        cloud = Hypotheses.empty(now)
        if force >= cue.min_force:
            cloud, _ = wrist_hypotheses(robot, cue.arm, cue.ft_link, hand_capsules(robot, cue.links), now)
        out.append((f"force_torque_{cue.name}", cloud))
    return out


@dataclass
class StationFusion:
    """Fuse one simulated robot's cues; ``publish`` receives every contact event and its ``inputs``.

    With ``publish_cloud`` the inputs are the messages of the clouds behind the event, and each
    cloud names the sensor messages it was computed from (``readings``: the robot state read).
    """

    robot: object
    publish: Callable[[ContactEvent, list[MsgId]], None]
    params: StationParams = field(default_factory=StationParams)
    events: list[ContactEvent] = field(default_factory=list)
    publish_cloud: CloudSink | None = None
    keyspace: KeySpace = field(default_factory=KeySpace)
    readings: Callable[[], list[MsgId]] = list

    def __post_init__(self) -> None:
        self.name = self.robot.spec.name
        self.cues = robot_cues(self.robot, self.params.min_force)
        self.loop = FusionLoop(IntegratorParams(timeout=0.3, wait_timeout=0.05, source_timeout=0.5),
                               CondensationParams(), TrackerParams(hold=self.params.hold))
        self._next = 0.0

    def __call__(self, robot: object) -> None:
        now = robot.time
        if now + 1e-9 < self._next:
            return
        self._next = now + 1.0 / self.params.rate_hz
        for cue in self.cues:
            for generator, cloud in cue_clouds(robot, cue, now):
                self._offer(generator, cloud, now, cue.hand)
        cycle = self.loop.step(now)  # every source offered this cycle: Algorithm 4.1's wait-all is met
        for ev in cycle.events if cycle is not None else ():
            self.events.append(ev)
            self.publish(ev, self.loop.inputs(ev.sources))

    def _offer(self, generator: str, cloud: Hypotheses, now: float, link: str) -> None:
        """Every source offers each cycle (empty when it feels nothing), and its cloud goes out on its key."""
        msg = None
        if self.publish_cloud is not None:
            msg = self.publish_cloud(self.keyspace.hypotheses(self.name, generator),
                                     HypothesisCloud.of(cloud, self.name, generator, link), self.readings())
        self.loop.offer(f"{self.name}/{generator}", cloud, now, self.name, link, msg)
