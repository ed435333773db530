"""Simulator prediction support generator (thesis §4.5.2): multi-contact, binary law.

A prediction scene (the simulator loaded with the robot, the environment and the objects at
their estimated poses) reports where contacts should be. Every predicted contact point gives
support hypotheses of fixed likelihood ``weight`` (0.5 in the thesis). The pose uncertainty
of the objects can be carried in two ways: run several prediction scenes with sampled object
poses (:func:`sample_poses`) and pass all their contacts, and/or dilate each predicted point
to the voxels within ``dilate`` of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.messages import PredictedState
from contactflow.fusion.generators.base import GeneratorModule
from contactflow.fusion.hypotheses import VOXEL_SIZE, Hypotheses, HypothesisType, voxelize
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.module import Port
from contactflow.nodes.status import Status


@dataclass(frozen=True)
class SimulatorParams:
    rate_hz: float = 30.0  # Hz
    robot: str = "robot"
    weight: float = 0.5  # likelihood of every support hypothesis (thesis §4.5.2)
    dilate: float = 0.0  # m, spread each predicted contact over the voxels this close
    voxel_size: float = VOXEL_SIZE  # m


def sample_poses(T: np.ndarray, sigma: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` copies of pose T with N(0, sigma) added to the position (thesis §4.7: sigma = 2 cm)."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"simulator: pose has shape {T.shape}, expected (4, 4)")
    out = np.repeat(T[None], n, axis=0)
    out[:, :3, 3] += rng.normal(0.0, sigma, (n, 3))
    return out


def _ball_offsets(radius: float, step: float) -> np.ndarray:
    k = int(np.floor(radius / step))
    g = np.arange(-k, k + 1) * step
    off = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    return off[np.linalg.norm(off, axis=1) <= radius + 1e-12]


def simulator_support(predicted: np.ndarray | Sequence[np.ndarray], stamp: float,
                      params: SimulatorParams | None = None) -> Hypotheses:
    """Support hypotheses at predicted contact points (one array or one per prediction scene)."""
    p = params or SimulatorParams()
    if not 0.0 <= p.weight <= 1.0:
        raise ValueError(f"simulator: weight={p.weight} must lie in [0, 1]")
    arrays = [predicted] if isinstance(predicted, np.ndarray) else list(predicted)
    pts = np.concatenate([np.asarray(a, dtype=float).reshape(-1, 3) for a in arrays]) if arrays else np.zeros((0, 3))
    if pts.shape[0] == 0:
        return Hypotheses.empty(stamp)
    if p.dilate > 0:
        pts = (pts[:, None, :] + _ball_offsets(p.dilate, p.voxel_size)[None]).reshape(-1, 3)
    h = Hypotheses.make(pts, p.weight, HypothesisType.SUPPORT, stamp=stamp, where="simulator")
    return voxelize(h, p.voxel_size, reduce="max")


class SimulatorSupportGenerator(GeneratorModule):
    """A robot's predictor's contacts to support hypotheses (§4.5.2): each predicted state's hand contacts,
    spread over ``dilate`` (the believed objects' pose error)."""

    Params = SimulatorParams
    inputs = (Port("predicted", PredictedState, "the robot's predictor's state (predict/<robot>/state): its hands' "
                   "predicted contact points, world"),)

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: SimulatorParams) -> dict[str, str]:
        return {"predicted": ks.predict(params.robot, "state")}

    def step(self) -> Status:
        assert self.io is not None
        frames = self.io.take("predicted")
        if not frames:
            return Status.RUNNING
        msg = frames[-1]
        assert isinstance(msg, PredictedState)
        pts = np.zeros((0, 3)) if msg.contacts is None else msg.contacts.numpy().astype(np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"{self.name}: input 'predicted' ({msg.robot}) has contacts of shape {pts.shape}, "
                             "expected (m, 3)")
        self.publish_cloud(simulator_support(pts, self.stamp_of(msg), self.params))
        return Status.RUNNING
