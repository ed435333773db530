"""Where on the hand a fused contact lies (thesis §4.4, Table 7.2): on a finger, on the palm, or on what the hand holds.

The robot's posed model (``RobotModel``) gives each link a bi-sphere and, for a hand's links, the
part it is (``regions``: finger or palm). A contact within ``margin`` of a hand link's surface lies
on that link; one farther out but within ``reach`` of the hand lies on something the hand carries
or pushes (a held object meeting the table); one beyond ``reach`` is on no part of the hand. A
contact is the centroid of its voxels: one spread over two fingertips has it between them, off both
surfaces, so the margin grows by the contact's spread (its sigma).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from contactflow.fusion.geometry import part_distances


class Region(StrEnum):
    FINGER = "finger"
    PALM = "palm"
    HELD_OBJECT = "held_object"


HAND_PARTS = (Region.FINGER, Region.PALM)
"""The regions a link of a robot model can be (``RobotModel.regions``); a held object is no link."""


@dataclass(frozen=True)
class RegionParams:
    margin: float = 0.015  # m, a contact this close to a hand link's surface lies on that link (voxels are 5 mm; F/T spreads ~1 cm)
    reach: float = 0.12  # m, beyond the margin and this close to the hand: on what the hand holds (the objects of §7.3 are < 12 cm across)

    def validate(self) -> None:
        if not 0.0 < self.margin < self.reach:
            raise ValueError(f"region margin={self.margin} and reach={self.reach}: need 0 < margin < reach")


def classify(points: np.ndarray, caps: np.ndarray, links: list[str], regions: list[str],
             params: RegionParams = RegionParams(), spread: np.ndarray | None = None) -> list[tuple[str, str]]:
    """Per point (n, 3), ``(region, link)``: the hand part it lies on and its link, ``held_object`` and the
    nearest hand link, or ``("", "")`` (on no hand, or the model names no hand part). ``spread`` (n,), m: each
    contact's sigma, added to the margin."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    extra = np.zeros(points.shape[0]) if spread is None else np.asarray(spread, dtype=np.float64).ravel()
    hand = np.flatnonzero([r in HAND_PARTS for r in regions])
    if hand.size == 0 or points.shape[0] == 0:
        return [("", "")] * points.shape[0]
    d = part_distances(points, caps[hand])
    best = d.argmin(axis=1)
    out = []
    for k, i in enumerate(best):
        link = links[hand[i]]
        if d[k, i] <= params.margin + extra[k]:
            out.append((str(regions[hand[i]]), link))
        elif d[k, i] <= params.reach:
            out.append((str(Region.HELD_OBJECT), link))
        else:
            out.append(("", ""))
    return out
