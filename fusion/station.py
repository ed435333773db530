"""A robot station's own contact fusion: its tactile and wrist F/T cues fused into contact events.

Runs beside the simulated robot at a fixed rate (thesis: fusion cycles at ~6-30 Hz): each
hand's pads and each arm's wrist sensor are sources of one integrator; condensation and the
event tracker turn the fused cloud into ``contact_made``/``contact_broken`` events that the
station publishes on ``contacts/fused/<robot>/events``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from contactflow.fusion.condensation import CondensationParams, condense
from contactflow.fusion.events import ContactEvent, ContactTracker, TrackerParams
from contactflow.fusion.generators.tactile import tactile_hypotheses
from contactflow.fusion.integrator import Integrator, IntegratorParams
from contactflow.fusion.sim_sources import hand_capsules, taxel_readings, wrist_hypotheses


@dataclass(frozen=True)
class StationParams:
    rate_hz: float = 20.0  # Hz, fusion cycles
    min_force: float = 1.5  # N, wrist forces below this feed no F/T source (noise, own weight)
    hold: float = 0.3  # s, a contact unseen this long is broken


@dataclass
class _Cue:
    name: str
    arm: str
    hand: str
    ft_link: str
    links: tuple[str, ...]
    min_force: float  # N, below this the wrist reading is noise


@dataclass
class StationFusion:
    """Fuse one simulated robot's cues; ``publish`` receives every contact event."""

    robot: object
    publish: Callable[[ContactEvent], None]
    params: StationParams = field(default_factory=StationParams)
    events: list[ContactEvent] = field(default_factory=list)

    def __post_init__(self) -> None:
        spec = self.robot.spec
        self.name = spec.name
        self.cues: list[_Cue] = []
        for arm in spec.arms:
            if not arm.hand:
                continue
            hand = spec.hand(arm.hand)
            ft = spec.ft(arm.ft) if arm.ft else None
            ft_link = ft.link if ft is not None else ""
            prefixes = tuple(p for p in (hand.palm_link, *hand.fingertips) if p) or (ft_link,)
            # 4 sigma above the sensor noise: an estimated wrench (Baxter) is far noisier
            floor = max(self.params.min_force, 4.0 * ft.force_noise) if ft is not None else self.params.min_force
            self.cues.append(_Cue(arm.name, arm.name, hand.name, ft_link, prefixes, floor))
        self.integrator = Integrator(IntegratorParams(timeout=0.3, wait_timeout=0.05, source_timeout=0.5))
        self.tracker = ContactTracker(TrackerParams(hold=self.params.hold))
        self.condensation = CondensationParams()
        self._next = 0.0

    def __call__(self, robot: object) -> None:
        now = robot.time
        if now + 1e-9 < self._next:
            return
        self._next = now + 1.0 / self.params.rate_hz
        for cue in self.cues:
            pressure, taxels, normals = taxel_readings(robot, cue.hand)
            if pressure.size and float(pressure.max()) > 0:
                cloud = tactile_hypotheses(pressure, taxels, now, normals)
                self.integrator.offer(f"{cue.name}/tactile", cloud, now, self.name, cue.hand)
            if cue.ft_link:
                force = np.linalg.norm(robot.ft(cue.arm).in_sensor_frame()[0])
                if force >= cue.min_force:
                    caps = hand_capsules(robot, cue.links)
                    cloud, _ = wrist_hypotheses(robot, cue.arm, cue.ft_link, caps, now)
                    self.integrator.offer(f"{cue.name}/ft", cloud, now, self.name, cue.hand)
        fused = self.integrator.integrate(now)
        for ev in self.tracker.update(condense(fused, self.condensation), now):
            self.events.append(ev)
            self.publish(ev)
