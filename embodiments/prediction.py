"""Prediction against sensing (thesis §5.5-5.7): the pure comparison behind a robot's predictor.

The predictor feeds, every world tick, what its simulation predicts (contact points of the
robot's hands, arm joints, wrist loads); the robot's fusion feeds its condensed contacts each
cycle and the world its measured joints and loads. :class:`MismatchDetector` says where they
disagree, each a :class:`Mismatch`:

- contacts are compared as presence per hand in time: a sensed contact on a hand at ``t`` is
  expected when the predictor had a contact on that hand at some time in
  ``[t - hold - window, t + window]`` (fusion keeps a contact ``hold`` s after its last sight);
  a predicted contact that pressed the hand's tactile pads (in the prediction) for ``sustain``
  is expected to be felt on the robot by its pads within ``[t - absent, t + window]``, or by its
  fusion within ``[t - absent - hold, t + window]`` (the prediction's pads and the robot's may
  differ when the grasp sits a few mm otherwise; a contact the fusion lost sight of for less than
  its tracker's ``hold`` is not broken for the robot either: a grasp that closes into its wrench's
  hypotheses can clear them for a quarter second, pads silent, while the can stays held). Fused contacts are placed on a hand, not on a point of it (a
  wrench's contact lies somewhere on the hand's surface), so the hand is what is compared; a
  sensed contact that names no hand counts where a predicted one lies within ``radius``. The
  decision for time ``t`` waits until both streams reached ``t + window``, so the lag between
  them does not matter.
- a sensed contact counts as unexpected once it lasted ``sustain`` (on every fused cycle);
- arm joints and wrist loads: a difference beyond ``joint_bound`` / ``force_bound`` that lasts
  ``sustain``;
- objects: perception seeing one more than ``object_bound`` from where the prediction holds it.

The same kind on the same hand or arm (or within ``radius``) is not reported again for ``quiet`` s: a
surprise that lasts is reported again every ``quiet`` s.
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from contactflow.embodiments.messages import MismatchKind

MISSING_STEP = 0.02  # s between two decisions on the predicted contacts (at most one per fused cycle or so)


@dataclass(frozen=True)
class MismatchParams:
    window: float = 0.1  # s, how far in time a counterpart may lie (the lag of fusion and of the reality gap)
    radius: float = 0.08  # m, how far a counterpart of a sensed contact that names no hand may lie
    hold: float = 0.3  # s fusion keeps a contact after its last sight (its tracker's hold)
    absent: float = 0.15  # s a hand's pads must feel nothing while the prediction presses them before a contact is missing
    sustain: float = 0.1  # s a predicted contact or a joint or load difference must last to count
    joint_bound: float = 0.1  # rad, arm joints (thesis Fig. 5.16: predicted joints within 0.1 rad)
    force_bound: float = 5.0  # N, external wrist force (median over the window)
    object_bound: float = 0.025  # m, a perceived object's distance from its prediction (thesis Fig. 5.16: within 2.5 cm)
    quiet: float = 1.0  # s, the same kind at the same place is not reported again sooner
    horizon: float = 3.0  # s of history kept

    def validate(self, where: str = "params") -> None:
        for f in ("window", "radius", "joint_bound", "force_bound", "object_bound", "horizon"):
            if not getattr(self, f) > 0:
                raise ValueError(f"{where}.{f}: {getattr(self, f)!r} must be > 0")
        for f in ("sustain", "quiet", "hold", "absent"):
            if not getattr(self, f) >= 0:
                raise ValueError(f"{where}.{f}: {getattr(self, f)!r} must be >= 0")
        if self.horizon < 2 * self.window + max(self.sustain, self.absent) + self.hold:
            raise ValueError(f"{where}.horizon: {self.horizon} s is shorter than 2 window + max(sustain, absent) + hold")


@dataclass(frozen=True)
class Mismatch:
    kind: MismatchKind
    since: float  # s, when the difference began (the evidence's time)
    location: tuple[float, ...] = ()  # m, world; () when it has no place
    part: str = ""  # the hand or arm concerned
    value: float = 0.0  # m (distance to the nearest counterpart, inf: none), rad or N
    bound: float = 0.0
    detail: str = ""
    delta: tuple[float, ...] = ()  # N, a load's difference: measured minus predicted (world axes)


def _median(x: np.ndarray) -> np.ndarray:
    """``np.median(x, axis=0)`` of finite values, through one sort (a fifth of np.median's time on a window)."""
    s = np.sort(x, axis=0)
    k = len(s)
    return s[k // 2] if k % 2 else (s[k // 2 - 1] + s[k // 2]) / 2


def _near(points: np.ndarray, x: np.ndarray) -> float:
    """Distance from ``x`` to the nearest of ``points`` (inf: none)."""
    if len(points) == 0:
        return float("inf")
    return float(np.sqrt(((points - x) ** 2).sum(axis=1).min()))


@dataclass
class _Stream:
    """Time-stamped point sets, oldest first; looked up by bisection on their times (a cycle's decisions
    read a few of the horizon's hundreds of samples)."""

    times: list[float] = field(default_factory=list)
    samples: list = field(default_factory=list)  # (t, (k, 3) points, hands, the hands whose contact can be felt)

    @property
    def t(self) -> float:
        return self.times[-1] if self.times else -np.inf

    def add(self, t: float, points: np.ndarray, hands: list[str], horizon: float, felt: set[str] | None = None) -> None:
        if self.times and t < self.times[-1]:
            return  # out of order: a late sample is older than what was decided on
        self.times.append(t)
        self.samples.append((t, np.asarray(points, dtype=np.float64).reshape(-1, 3), hands,
                             set(hands) if felt is None else felt))
        old = bisect_left(self.times, t - horizon)
        if old:
            del self.times[:old], self.samples[:old]

    def after(self, t: float) -> list:
        """The samples later than ``t``."""
        return self.samples[bisect_right(self.times, t):]

    def within(self, a: float, b: float) -> tuple[np.ndarray, set[str]]:
        """The points and the hands of the samples in ``[a, b]``."""
        found = [(p, h) for _, p, h, _ in self.samples[bisect_left(self.times, a - 1e-9):bisect_right(self.times, b + 1e-9)]
                 if len(p)]
        pts = np.concatenate([p for p, _ in found]) if found else np.zeros((0, 3))
        return pts, {x for _, h in found for x in h}

    def at(self, t: float) -> tuple[float, np.ndarray, list[str], set[str]] | None:
        """The newest sample at or before ``t``."""
        i = bisect_right(self.times, t + 1e-9)
        return self.samples[i - 1] if i else None


class MismatchDetector:
    """Predicted and sensed contacts, joints and loads in; the mismatches between them out."""

    def __init__(self, params: MismatchParams | None = None) -> None:
        self.params = params or MismatchParams()
        self.params.validate()
        self.predicted = _Stream()
        self.sensed = _Stream()
        self.touched = _Stream()
        self._decided = -np.inf  # sensed samples up to this time are decided
        self._missing_at = -np.inf  # predicted samples up to this time are decided
        self._reported: list[tuple[MismatchKind, float, np.ndarray | None, str]] = []
        self._unexpected: list[tuple[str, np.ndarray, float]] = []  # (hand, place, since) sensed, none predicted
        self._over: dict[tuple[str, str], list] = {}  # (what, name) -> [over since, under since, last reported]
        self._loads: dict[str, deque] = {}  # arm -> (t, predicted (3,) then measured (3,), steady), oldest first
        self._loads_decided: dict[str, float] = {}
        self.counts: dict[MismatchKind, int] = {k: 0 for k in MismatchKind}

    # -- inputs ----------------------------------------------------------------------------------
    def predict(self, t: float, points: np.ndarray, hands: list[str], felt: set[str] | None = None) -> None:
        """The predicted contact points after the tick at ``t``, the hand each lies on, and the hands whose
        contact the robot's sensors can feel (default: all; a brush lighter than the sensors' floor is not)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(hands) != len(pts) or "" in hands:
            raise ValueError(f"predict: {len(pts)} points need as many hand names, got {hands!r}")
        self.predicted.add(t, pts, list(hands), self.params.horizon, felt)

    def touch(self, t: float, pressed: set[str]) -> None:
        """The hands whose tactile pads the robot measures pressed at ``t`` (every reading, also when none is)."""
        self.touched.add(t, np.zeros((len(pressed), 3)), sorted(pressed), self.params.horizon)

    def sense(self, t: float, points: np.ndarray, hands: list[str]) -> None:
        """The robot's fused contacts of the cycle at ``t`` (every cycle, also an empty one) and the hand
        each lies on ("": unknown)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(hands) != len(pts):
            raise ValueError(f"sense: {len(pts)} points need as many hand names, got {hands!r}")
        self.sensed.add(t, pts, list(hands), self.params.horizon)

    def joints(self, t: float, error: float, joint: str = "") -> Mismatch | None:
        """The largest arm joint difference at ``t`` (rad)."""
        p = self.params
        return self._bound(MismatchKind.JOINTS, t, "joints", joint, error, p.joint_bound,
                           f"arm joint {joint} is {error:.3f} rad from the predicted")

    def object(self, t: float, name: str, seen: np.ndarray, gap: float) -> Mismatch | None:
        """Perception saw object ``name`` at ``seen`` (world), ``gap`` m from where the prediction holds it."""
        p = self.params
        if not gap > p.object_bound:
            return None
        found = self._report(MismatchKind.OBJECT, t, t, np.asarray(seen, dtype=np.float64), name, gap, p.object_bound,
                             f"{name} was seen at {_fmt(np.asarray(seen))}, {100 * gap:.1f} cm from its prediction")
        return found[0] if found else None

    def force(self, t: float, arm: str, predicted: np.ndarray, measured: np.ndarray, steady: bool = True) -> None:
        """The predicted and measured external wrist forces of ``arm`` at ``t`` (N, world axes); compared in
        :meth:`check` as their medians over ``[t - window, t + window]`` (an impact a few ticks off, or a
        contact's chatter, is no surprise), where the predicted hand was ``steady`` all along that window
        (free, or holding an object aloft; not pushing one over the table, nor setting it down)."""
        series = self._loads.setdefault(arm, deque())
        series.append((t, np.concatenate([np.asarray(predicted, dtype=np.float64).reshape(3),
                                          np.asarray(measured, dtype=np.float64).reshape(3)]), bool(steady)))
        while series and series[0][0] < t - self.params.horizon:
            series.popleft()

    def _check_loads(self) -> list[Mismatch]:
        p = self.params
        out = []
        for arm, series in self._loads.items():
            done = self._loads_decided.get(arm, -np.inf)
            last = series[-1][0]
            if last - p.window <= done:
                continue  # no sample since the last decision is a window old yet
            # the samples a window of a time not yet decided reaches: the newest few of the horizon's hundreds
            tail = []
            for x in reversed(series):
                if x[0] < done - p.window - 1e-9:
                    break
                tail.append(x)
            tail.reverse()
            ts = np.array([x[0] for x in tail])
            loads = np.array([x[1] for x in tail]).reshape(-1, 6)
            steady = np.array([x[2] for x in tail], dtype=bool)
            for t in ts[ts <= last - p.window].tolist():
                if t <= done:
                    continue
                done = t
                lo = int(np.searchsorted(ts, t - p.window - 1e-9, side="left"))
                hi = int(np.searchsorted(ts, t + p.window + 1e-9, side="right"))
                if not steady[lo:hi].all():
                    continue
                # medians over the window: a contact's chatter (tens of N from one tick to the next, in the world
                # and in the prediction alike, out of phase) is not a difference in load
                median = _median(loads[lo:hi])
                delta = median[3:] - median[:3]
                error = float(np.linalg.norm(delta))
                m = self._bound(MismatchKind.FORCE, t, "force", arm, error, p.force_bound,
                                f"the wrist of {arm} feels {error:.2f} N other than predicted",
                                tuple(float(v) for v in delta))
                out += [m] if m is not None else []
            self._loads_decided[arm] = done
        return out

    # -- decisions -------------------------------------------------------------------------------
    def check(self) -> list[Mismatch]:
        """The mismatches decidable now: of every sensed cycle, pad reading and wrist load that the predicted
        stream passed by ``window`` (and the sensed streams, for a predicted contact)."""
        p = self.params
        out: list[Mismatch] = self._check_loads()
        horizon = min(self.predicted.t, self.sensed.t) - p.window
        for t, sensed, hands, _ in self.sensed.after(self._decided):
            if t > horizon:
                break
            if t <= self._decided:
                continue  # a sample of the same time as one decided
            self._decided = t
            pred_pts, pred_hands = self.predicted.within(t - p.hold - p.window, t + p.window)
            going: list[tuple[str, np.ndarray, float]] = []
            for x, hand in zip(sensed, hands, strict=True):
                if hand in pred_hands:
                    continue
                d = _near(pred_pts, x)
                if not (hand or d > p.radius):
                    continue
                since = next((s for h, y, s in self._unexpected
                              if h == hand and (hand or float(np.linalg.norm(x - y)) <= p.radius)), t)
                going.append((hand, x, since))
                if t - since >= p.sustain - 1e-9:
                    out += self._report(MismatchKind.UNEXPECTED_CONTACT, since, t, x, hand, d, p.radius,
                                        f"a contact sensed at {_fmt(x)} on {hand or 'the robot'} where none "
                                        f"was predicted")
            # one cycle without it ends an episode: a contact that outlives its prediction by a cycle or two (a
            # hand that lets go of a can a little later than predicted) is no surprise
            self._unexpected = going
        horizon = min(self.predicted.t, self.touched.t, self.sensed.t) - p.window
        for t, points, hands, felt in self.predicted.after(self._missing_at):
            if t > horizon:
                break
            if t < self._missing_at + MISSING_STEP:
                continue
            self._missing_at = t
            before = self.predicted.at(t - p.sustain)
            if before is None:
                continue
            _, pressed = self.touched.within(t - p.absent, t + p.window)
            _, fused = self.sensed.within(t - p.absent - p.hold, t + p.window)
            # pressed a while in the prediction; on the robot neither its pads nor its fusion feel the hand touch
            for hand in sorted((felt & before[3] & set(hands)) - pressed - fused):
                x = points[hands.index(hand)]
                out += self._report(MismatchKind.MISSING_CONTACT, t, t, x, hand, -1.0, p.absent,
                                    f"a contact predicted at {_fmt(x)} on {hand} did not press its pads")
        return out

    def _bound(self, kind: MismatchKind, t: float, what: str, name: str, value: float, bound: float,
               detail: str, delta: tuple[float, ...] = ()) -> Mismatch | None:
        """A difference over ``bound`` for ``sustain`` s starts an episode, under it for ``sustain`` s ends it (a
        difference that hovers at the bound is one surprise, not many); an episode is reported when it starts
        and again every ``quiet`` s while it lasts (a watcher that starts late still hears of it)."""
        key = (what, name)
        episode = self._over.get(key)
        if not value > bound:
            if episode is not None:
                episode[1] = t if episode[1] is None else episode[1]
                if t - episode[1] >= self.params.sustain:
                    del self._over[key]
            return None
        if episode is None:
            episode = self._over[key] = [t, None, -np.inf]  # since, under since, last reported
        episode[1] = None
        if t - episode[2] < self.params.quiet or t - episode[0] < self.params.sustain:
            return None
        episode[2] = t
        found = self._report(kind, episode[0], t, None, name, value, bound, detail, delta)
        return found[0] if found else None

    def _report(self, kind: MismatchKind, since: float, now: float, x: np.ndarray | None, part: str, value: float,
                bound: float, detail: str, delta: tuple[float, ...] = ()) -> list[Mismatch]:
        p = self.params
        self._reported = [r for r in self._reported if now - r[1] < p.quiet]
        for k, _, y, name in self._reported:
            same_place = name == part if (part or x is None) else (
                y is not None and float(np.linalg.norm(x - y)) <= p.radius)
            if k is kind and same_place:
                return []
        self._reported.append((kind, now, None if x is None else np.array(x, dtype=float), part))
        self.counts[kind] += 1
        where = () if x is None else tuple(float(v) for v in x)
        return [Mismatch(kind, since, where, part, value, bound, detail, delta)]


def held_mass(mass: float, delta: np.ndarray, payload: float, vertical: float = 0.8, gravity: float = 9.81) -> float | None:
    """The mass (kg) of an object held aloft, believed ``mass``, that explains a wrist load ``delta`` (N, measured
    minus predicted, world axes, z up) as weight: ``None`` when it is no weight (less than ``vertical`` of it along
    gravity: a push, a snag) or the mass it asks for is none or beyond the arm's ``payload`` (a pull, not a load)."""
    d = np.asarray(delta, dtype=np.float64).reshape(3)
    norm = float(np.linalg.norm(d))
    if norm == 0.0 or abs(d[2]) < vertical * norm:
        return None
    learned = mass - float(d[2]) / gravity
    return learned if 0.0 < learned <= payload else None


def _fmt(x: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in x) + ") m"
