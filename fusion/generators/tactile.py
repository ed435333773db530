"""Tactile hypotheses generator (thesis §4.4.2, eq. 4.6): multi-contact, value law.

Every taxel whose pressure exceeds the noise floor gives a regular hypothesis at its world
position with likelihood p(c|x, z) = z_x / max(z). The force is the taxel pressure times its
area and, when taxel normals are known, pushes into the pad (direction = -normal).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.fusion.generators.base import GeneratorModule, array_of
from contactflow.fusion.hypotheses import (
    VOXEL_SIZE,
    Hypotheses,
    HypothesisType,
    normalise,
    voxelize,
)
from contactflow.nodes.messages import Array
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


class TactileGenerator(GeneratorModule):
    """Tactile arrays to contact hypotheses (eq. 4.6)."""

    Params = TactileParams
    inputs = (Port("taxels", Array, "(n, 4) [x, y, z, pressure] or (n, 7) with the taxel normal, world"),)

    def step(self) -> Status:
        assert self.io is not None
        for msg in self.io.take("taxels"):
            a = array_of(msg, "taxels", (4, 7), self.name)
            assert a is not None
            normals = a[:, 4:7] if a.shape[1] == 7 else None
            self.publish_cloud(tactile_hypotheses(a[:, 3], a[:, :3], self.stamp_of(msg), normals, self.params))
        return Status.RUNNING
