"""Contact cues of a simulated robot as generator inputs: taxels, hand model and F/T hypotheses.

These adapters read only what a real robot would give (tactile pressures with the pads'
known geometry posed by forward kinematics, the wrist wrench, the spherical model); the
Table 4.1 benchmark and the robot stations' fusion share them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from contactflow.fusion.generators.force_torque import ForceTorqueParams, ft_hypotheses, hand_box
from contactflow.fusion.geometry import distance_fn
from contactflow.fusion.hypotheses import Hypotheses

FT_BAND = 0.02  # m, F/T hypotheses kept this close to the hand model (bi-sphere fitting error)


def stope_capsules(sph, sel: Sequence[int] | np.ndarray) -> np.ndarray:
    """The posed bi-spheres ``[c1, r1, c2, r2]`` (k, 8) of s-topes ``sel`` of a spherical model."""
    return np.concatenate([sph.C1[sel], sph.r1[sel, None], sph.C2[sel], sph.r2[sel, None]], axis=1)


def hand_capsules(robot, link_prefixes: Sequence[str]) -> np.ndarray:
    """The posed bi-spheres ``[c1, r1, c2, r2]`` (k, 8) of the links whose names start with a prefix."""
    sph = robot.spherical
    return stope_capsules(sph, [i for i, link in enumerate(sph.links) if any(link.startswith(p) for p in link_prefixes)])


def taxel_readings(robot, hand: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pressure (n,), world taxel positions (n,3), world normals (n,3)) of every pad of ``hand``."""
    from contactflow.embodiments.modules.model_publisher import pad_taxels

    pressures, positions, normals = [], [], []
    readings = robot.tactile(hand)
    for pad in robot.spec.hand(hand).pads:
        T = robot.frame_pose(pad.link)
        local, nl = (a.reshape(-1, 3) for a in pad_taxels(pad))
        positions.append(local @ T[:3, :3].T + T[:3, 3])
        normals.append(nl @ T[:3, :3].T)
        pressures.append(readings[pad.name].ravel())
    if not pressures:
        return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(pressures), np.concatenate(positions), np.concatenate(normals)


def wrist_hypotheses(robot, arm: str, ft_link: str, caps: np.ndarray, now: float,
                     band: float = FT_BAND) -> tuple[Hypotheses, tuple]:
    """F/T hypotheses (eq. 4.8-4.9) inside the hand's bounding box; also the wrench used: the external
    one (the hand's own weight removed, not a primitive's tare, so a load that falls reads as none)."""
    T_s = robot.frame_pose(ft_link)
    f_s, tau_s = robot.ft(arm).external_in_sensor_frame()
    lo, hi = hand_box(caps, T_s)
    params = ForceTorqueParams(box_lo=lo, box_hi=hi, surface_band=band)
    return ft_hypotheses(f_s, tau_s, T_s, distance_fn(caps), now, params), (f_s, tau_s, T_s, caps)
