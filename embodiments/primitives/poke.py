"""Poke: come straight down at each of a row of spots until a touch and go back up: a blind map of what stands on a support."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from contactflow.embodiments.primitives.base import Capability, Primitive
from contactflow.nodes.status import Event

CLOSE = 0.004  # m, the controlled frame is at a spot (or its height) this close to it


class Phase(Enum):
    """Where a poke is: the hand taking its preshape, moving over a spot, coming down, leaning on a touch, going up."""

    SHAPE = "shape"
    OVER = "over"
    DOWN = "down"
    LEAN = "lean"
    UP = "up"


class Poke(Primitive):
    """Guarded touches without vision (exploration by contact, thesis §3.4.3 and ch. 4).

    Above each of ``spots`` (world [x, y, ...] of the controlled frame, at ``height``) the hand
    comes straight down at ``velocity`` until its wrist senses more than ``force_threshold`` or a
    pad touches, or the controlled frame reaches ``floor_z`` (the support: nothing there), stays on
    a touch so the robot's contact generators see it for a few fusion cycles, and goes back up to
    ``height`` before it moves on. Where it touched is the contact
    fusion's to tell (the touches go into the robot's and its cell's contact map); the primitive
    counts them: SUCCESS with ``touches`` after the last spot, OBJECT_NOT_FOUND when no spot met
    anything above the support. On a touch it leans on at ``lean`` m/s for ``dwell`` s or up to
    ``press`` N: stopped at the first newtons, the hand springs back off the object within a few
    milliseconds, too briefly for the wrist's cue at a fusion's pace.
    """

    requires = Capability(ft=True)
    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.CONTACT, Event.OBJECT_NOT_FOUND)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        spots: tuple[float, ...] = ()  # m, flat [x, y, ...] (world) of the controlled frame, visited in order
        height: float = 0.9  # m, world z of the controlled frame for the moves between spots
        floor_z: float = 0.0  # m, world z of the controlled frame at which the hand meets the support
        force_threshold: float = 2.0  # N, a touch on the wrist
        velocity: float = 0.05  # m/s, coming down
        travel: float = 0.12  # m/s, going up and between spots
        slow_down: float = 4.0  # 1/s, going up and between spots the speed falls to this much per m left (arrives without overshoot)
        dwell: float = 0.4  # s on a touch, leaning on
        lean: float = 0.004  # m/s, down while it leans on a touch
        press: float = 15.0  # N, it leans on a touch up to this force
        preshape: str = "closed"  # hand preshape while poking ("" = keep)

        def validate(self) -> None:
            if min(self.velocity, self.travel, self.slow_down, self.force_threshold, self.lean) <= 0 or self.dwell < 0:
                raise ValueError("velocity, travel, slow_down, lean and force_threshold must be > 0, dwell >= 0")
            if self.press <= self.force_threshold:
                raise ValueError(f"press={self.press} N must be over force_threshold={self.force_threshold} N")

    def begin(self) -> None:
        p = self.params
        if not p.spots or len(p.spots) % 2:
            raise ValueError(f"{self.name}.params.spots: expected [x, y, ...] pairs, got {len(p.spots)} values")
        if p.floor_z >= p.height:
            raise ValueError(f"{self.name}.params.floor_z={p.floor_z} must be below height={p.height} m")
        self.spots = np.asarray(p.spots, dtype=np.float64).reshape(-1, 2)
        self.k, self.touches, self.phase, self.since = 0, 0, Phase.SHAPE, self.r.time
        if p.preshape and self.hand_name:
            self.hand.preshape(p.preshape)

    def update(self) -> None:
        p = self.params
        pos = self.r.frame_pose(self.ee_frame)[:3, 3]
        if self.phase == Phase.SHAPE:
            if not self.hand_name or self.hand.done() or self.elapsed > 1.5:
                self.phase = Phase.OVER
        elif self.phase == Phase.OVER:
            err = np.array([*(self.spots[self.k] - pos[:2]), p.height - pos[2]])
            if np.linalg.norm(err) < CLOSE:
                self.halt()
                self.r.tare_ft(self.arm_name)
                self.phase = Phase.DOWN
            else:
                self.twist(np.concatenate([err / np.linalg.norm(err) * self._speed(float(np.linalg.norm(err))), np.zeros(3)]))
        elif self.phase == Phase.DOWN:
            if np.linalg.norm(self.wrench_in("world")[:3]) > p.force_threshold or self.pads_in_contact():
                self.halt()
                self.touches += 1
                self.emit_once(Event.CONTACT, f"spot {self.k + 1}: touched at {pos[2]:.3f} m", {"spot": float(self.k)})
                self.phase, self.since = Phase.LEAN, self.r.time
            elif pos[2] <= p.floor_z:
                self.halt()
                self.phase = Phase.UP
            else:
                self.twist(np.array([0.0, 0.0, -p.velocity, 0.0, 0.0, 0.0]))
        elif self.phase == Phase.LEAN:
            # a touch stopped at its first newtons springs back off the object within a few ms, too briefly for a
            # wrist cue at a fusion's pace: the hand leans on at a crawl, up to press N
            if self.r.time - self.since >= p.dwell or np.linalg.norm(self.wrench_in("world")[:3]) >= p.press:
                self.halt()
                self.phase = Phase.UP
            else:
                self.twist(np.array([0.0, 0.0, -p.lean, 0.0, 0.0, 0.0]))
        elif p.height - pos[2] < CLOSE:  # Phase.UP: up
            self.halt()
            self.k += 1
            if self.k == len(self.spots):
                if self.touches:
                    self.succeed(f"{self.touches} touches at {len(self.spots)} spots", touches=float(self.touches))
                else:
                    self.fail(f"nothing above the support at {len(self.spots)} spots", event=Event.OBJECT_NOT_FOUND,
                              touches=0.0)
                return
            self.phase = Phase.OVER
        else:
            self.twist(np.array([0.0, 0.0, self._speed(p.height - pos[2]), 0.0, 0.0, 0.0]))

    def _speed(self, left: float) -> float:
        """m/s toward a spot or the height ``left`` m away: travel, slowing down near it (1 cm/s at the end)."""
        return min(self.params.travel, self.params.slow_down * left + 0.01)
