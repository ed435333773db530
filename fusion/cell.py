"""One contact map per cell: the hypothesis clouds of every robot of a cell fused into one map and its events.

Robots that share a table share what they touched (thesis ch. 4 across robots): a ``cell_fusion``
module reads the clouds of every generator of the cell's robots, weighs each source by its
reliability, and publishes the cell's fused hypotheses, contacts and contact events on
``contacts/fused/<cell>/...``, which any robot's modules subscribe to. It refuses, and counts
by reason, a cloud about a robot outside the cell (another cell's or another site's), one
stamped further from its clock than ``max_skew``, and a robot's clouds beyond ``max_rate``
(a flooding robot is throttled; the others' clouds still come through).
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from dataclasses import dataclass

from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.messages import HypothesisCloud
from contactflow.fusion.service import ContactFusion, FusionParams


@dataclass(frozen=True)
class CellFusionParams(FusionParams):
    robot: str = "cell"  # the cell's name: its map goes out on contacts/fused/<cell>/{hypotheses,contacts,events}
    robots: tuple[str, ...] = ()  # the cell's robots; a cloud about any other robot is refused
    reliability: tuple[str, ...] = ()  # "<robot>=w" or "<robot>/<generator>=w", w in (0, 1]: likelihoods times w
    max_skew: float = 2.0  # s, a cloud stamped further than this from the node's clock (another clock) is refused
    max_rate: float = 500.0  # Hz, clouds of one robot taken per second, all its generators (a second's burst)

    def validate(self) -> None:
        super().validate()
        if not self.robots:
            raise ValueError("robots: a cell fusion needs the cell's robots")
        if self.max_skew <= 0 or self.max_rate <= 0:
            raise ValueError(f"max_skew={self.max_skew} and max_rate={self.max_rate} must be > 0")
        self.weights()

    def weights(self) -> dict[str, float]:
        """Reliability by ``robot`` or ``robot/generator`` (the more specific one wins)."""
        out: dict[str, float] = {}
        for entry in self.reliability:
            name, sep, value = entry.partition("=")
            try:
                w = float(value)
            except ValueError:
                w = float("nan")
            if not sep or not name or not 0.0 < w <= 1.0:
                raise ValueError(f"reliability {entry!r}: expected '<robot>[/<generator>]=w' with w in (0, 1]")
            if name.split("/")[0] not in self.robots:
                raise ValueError(f"reliability {entry!r}: robot {name.split('/')[0]!r} is not one of robots "
                                 f"{list(self.robots)}")
            out[name] = w
        return out


class CellFusion(ContactFusion):
    """The contact fusion of a cell: every robot's hypotheses in one voxel space (see the module docstring)."""

    Params = CellFusionParams

    def reset(self) -> None:
        super().reset()
        self.weights = self.params.weights()
        self.refused: Counter[str] = Counter()  # reason -> clouds refused
        self._bucket: dict[str, tuple[float, float]] = {}  # robot -> (tokens, when last refilled)

    def on_params(self, old) -> None:  # type: ignore[no-untyped-def]
        super().on_params(old)
        self.weights = self.params.weights()

    def status_detail(self) -> str:
        """How many sources of each robot of the cell feed the map, and the refusals (``contactflow ls``)."""
        plugged = Counter(s.robot for s in self.integrator.sources.values())
        refused = ", ".join(f"{why} {n}" for why, n in sorted(self.refused.items())) or "none"
        return f"sources: {', '.join(f'{r} {plugged[r]}' for r in self.params.robots)}; refused: {refused}"

    def admit(self, msg: HypothesisCloud, now: float) -> Hypotheses | None:
        p = self.params
        if msg.robot not in p.robots:
            return self._refuse("robot", f"a cloud about robot {msg.robot!r}, not of this cell {list(p.robots)}")
        if abs(msg.stamp - now) > p.max_skew:
            return self._refuse("skew", f"{msg.source}: stamped {msg.stamp:.3f} s, {msg.stamp - now:+.3f} s from "
                                        f"the clock (max_skew {p.max_skew:g} s)")
        if not self._take_token(msg.robot, now):
            return self._refuse("rate", f"{msg.robot}: over {p.max_rate:g} clouds/s")
        cloud = msg.hypotheses()
        w = self.weights.get(msg.source, self.weights.get(msg.robot, 1.0))
        return cloud if w == 1.0 else dataclasses.replace(cloud, likelihood=cloud.likelihood * w)

    def _take_token(self, robot: str, now: float) -> bool:
        rate = self.params.max_rate
        tokens, last = self._bucket.get(robot, (rate, now))
        tokens = min(rate, tokens + (now - last) * rate)
        ok = tokens >= 1.0
        self._bucket[robot] = (tokens - 1.0 if ok else tokens, now)
        return ok

    def _refuse(self, why: str, detail: str) -> None:
        self.refused[why] += 1
        n = self.refused[why]
        if n <= 3 or n % 1000 == 0:  # a flood of refusals is counted, not logged line by line
            assert self.io is not None
            self.io.log(f"refused #{n} ({why}): {detail}")
        return None
