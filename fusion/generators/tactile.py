"""Tactile hypotheses generator (thesis §4.4.2, eq. 4.6): multi-contact, value law.

Every taxel whose pressure exceeds the noise floor gives a regular hypothesis at its world
position with likelihood p(c|x, z) = z_x / max(z). The force is the taxel pressure times its
area and, when taxel normals are known, pushes into the pad (direction = -normal). The shell
reads the hand's ``TactileArray`` and places its taxels with the ``TaxelPoses`` the robot
model publisher computes from the joint state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.messages import TactileArray, TaxelPoses
from contactflow.fusion.generators.base import GeneratorModule
from contactflow.fusion.hypotheses import (
    VOXEL_SIZE,
    Hypotheses,
    HypothesisType,
    normalise,
    voxelize,
)
from contactflow.nodes.module import Port
from contactflow.nodes.status import Status


@dataclass(frozen=True)
class TactileParams:
    rate_hz: float = 30.0  # Hz
    robot: str = "robot"
    noise_floor: float = 0.05  # pressure units; readings at or below are no contact
    taxel_area: float = 1.0  # force per pressure unit (1 when pressure is already N per taxel)
    voxel_size: float = VOXEL_SIZE  # m


def tactile_hypotheses(pressure: np.ndarray, taxels: np.ndarray, stamp: float,
                       normals: np.ndarray | None = None, params: TactileParams | None = None) -> Hypotheses:
    """Hypotheses from taxel pressures (n,) at world positions (n, 3); eq. 4.6."""
    p = params or TactileParams()
    z = np.asarray(pressure, dtype=np.float64).ravel()
    pos = np.asarray(taxels, dtype=np.float64).reshape(-1, 3)
    if z.shape[0] != pos.shape[0]:
        raise ValueError(f"tactile: {z.shape[0]} pressures for {pos.shape[0]} taxel positions")
    if normals is not None and np.shape(normals) != pos.shape:
        raise ValueError(f"tactile: normals shape {np.shape(normals)} != taxel positions {pos.shape}")
    active = z > p.noise_floor
    if not active.any():
        return Hypotheses.empty(stamp)
    za = z[active]
    direction = None if normals is None else -normalise(np.asarray(normals, dtype=np.float64)[active])
    h = Hypotheses.make(pos[active], za / za.max(), HypothesisType.REGULAR, za * p.taxel_area, direction, stamp,
                        where="tactile")
    return voxelize(h, p.voxel_size, reduce="max")


def placed_pressures(tactile: TactileArray, taxels: TaxelPoses, module: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pressure (n,), world positions (n, 3), world normals (n, 3)) of one hand's reading."""
    where = f"{module}: hand {tactile.hand!r}"
    if tactile.pads != taxels.pads:
        raise ValueError(f"{where}: tactile pads {tactile.pads} differ from taxel pose pads {taxels.pads}")
    p = tactile.pressure.numpy().astype(np.float64)
    pos = taxels.positions.numpy().astype(np.float64)
    nrm = taxels.normals.numpy().astype(np.float64)
    if pos.shape != (*p.shape, 3) or nrm.shape != pos.shape:
        raise ValueError(f"{where}: pressure {p.shape}, taxel positions {pos.shape} and normals {nrm.shape} "
                         "do not match (expected (pads, rows, cols) and (pads, rows, cols, 3))")
    if not (np.isfinite(p).all() and np.isfinite(pos).all() and np.isfinite(nrm).all()):
        raise ValueError(f"{where}: pressures or taxel poses contain NaN or inf")
    return p.ravel(), pos.reshape(-1, 3), nrm.reshape(-1, 3)


class TactileGenerator(GeneratorModule):
    """Tactile arrays to contact hypotheses (eq. 4.6), one cloud per hand reading (link = the hand)."""

    Params = TactileParams
    inputs = (
        Port("tactile", TactileArray, "pressure images of one hand's pads, N per taxel"),
        Port("taxels", TaxelPoses, "world taxel positions and normals of the hand, posed from the joint state"),
    )

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        self.reset()

    def reset(self) -> None:
        self.taxels: dict[str, TaxelPoses] = {}

    def step(self) -> Status:
        assert self.io is not None
        for poses in self.io.take("taxels"):
            self.taxels[poses.hand] = poses  # type: ignore[attr-defined]
        newest: dict[str, TactileArray] = {}
        for msg in self.io.take("tactile"):
            newest[msg.hand] = msg  # type: ignore[attr-defined]
        for hand, msg in newest.items():
            poses = self.taxels.get(hand)
            if poses is None:
                continue  # the hand's taxels are not placed yet (no joint state seen)
            pressure, positions, normals = placed_pressures(msg, poses, self.name)
            self.publish_cloud(tactile_hypotheses(pressure, positions, self.stamp_of(msg), normals, self.params),
                               link=hand)
        return Status.RUNNING
