"""Contact condensation (thesis §4.6.2): from the fused hypothesis cloud to located contacts.

Three methods: ``threshold`` (keep voxels with H(x) >= threshold, one contact at their
weighted centroid), ``centroid`` (the likelihood-weighted centroid of every voxel) and
``cluster`` (threshold, euclidean clustering with open3d's DBSCAN, one likelihood-weighted
centroid per cluster: the method of §4.7, which separates two contacts, Fig. 4.12). Each
contact carries its location, likelihood, spread σ (the likelihood-weighted RMS distance of
its voxels to the centroid, Table 4.1), mean force and direction, and the robot and link of
the regular source that contributed most to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from contactflow.fusion.hypotheses import normalise
from contactflow.fusion.integrator import Fused
from contactflow.recognition import open3d_backend


class Method(StrEnum):
    THRESHOLD = "threshold"
    CENTROID = "centroid"
    CLUSTER = "cluster"


@dataclass(frozen=True)
class CondensationParams:
    method: Method = Method.CLUSTER
    threshold: float = 0.02  # absolute floor on H(x) (thesis: 0.6 for threshold, 0.1 for cluster,
    # with its generators; 1/n laws here put single-contact clouds near 0.05 per voxel)
    relative_threshold: float = 0.1  # floor as a fraction of the largest H(x) of the cycle
    cluster_eps: float = 0.012  # m, neighbour distance of the euclidean clustering
    min_points: int = 1  # voxels for a cluster core point (1: plain euclidean clustering)
    min_mass: float = 0.3  # a cluster is a contact when its likelihoods sum to this

    def validate(self) -> None:
        if not 0.0 <= self.threshold <= 1.0:
            raise ValueError(f"threshold={self.threshold} must lie in [0, 1]")
        if not 0.0 <= self.relative_threshold <= 1.0:
            raise ValueError(f"relative_threshold={self.relative_threshold} must lie in [0, 1]")
        if not self.cluster_eps > 0:
            raise ValueError(f"cluster_eps={self.cluster_eps} must be > 0")
        if self.min_points < 1:
            raise ValueError(f"min_points={self.min_points} must be >= 1")


@dataclass(frozen=True)
class Contact:
    location: np.ndarray  # (3,) m, world frame
    likelihood: float  # sum of the cluster's H(x), capped at 1
    sigma: float  # m, likelihood-weighted RMS distance of the voxels to the centroid
    force: float  # N
    direction: np.ndarray  # (3,) unit, zero if unknown
    voxels: int
    sources: int  # bitmask of the columns that contributed
    robot: str = ""
    link: str = ""


def _contact(fused: Fused, idx: np.ndarray) -> Contact:
    w = fused.likelihood[idx]
    pts = fused.location[idx]
    wsum = float(w.sum())
    c = (w[:, None] * pts).sum(axis=0) / wsum
    sigma = float(np.sqrt((w * ((pts - c) ** 2).sum(axis=1)).sum() / wsum))
    force = float((w * fused.force[idx]).sum() / wsum)
    direction = normalise((w[:, None] * fused.direction[idx]).sum(axis=0))
    sources = int(np.bitwise_or.reduce(fused.sources[idx])) if idx.size else 0
    robot = link = ""
    if fused.per_source.shape[1]:
        mass = fused.per_source[idx].sum(axis=0)
        # the link of the source with the most evidence among those that name one: a support or null
        # cloud spanning both hands (motion, null) names none, and a voxel it supports stays on its link
        named = np.array([bool(lk) for lk in fused.links[:mass.size]])
        if named.any() and mass[named].max() > 0:
            mass = np.where(named, mass, -np.inf)
        col = int(np.argmax(mass))
        robot, link = fused.robots[col], fused.links[col]
    return Contact(c, min(1.0, wsum), sigma, force, direction, int(idx.size), sources, robot, link)


def condense(fused: Fused, params: CondensationParams | None = None) -> list[Contact]:
    """The contacts of one fused cloud, most likely first."""
    p = params or CondensationParams()
    if len(fused) == 0:
        return []
    lik = fused.likelihood
    if p.method == Method.CENTROID:
        floor = 0.0  # the weighted centroid of every voxel
    else:
        floor = max(p.threshold, p.relative_threshold * float(lik.max()))
    idx = np.flatnonzero(lik >= floor)
    if idx.size == 0:
        return []
    if p.method in (Method.THRESHOLD, Method.CENTROID):
        groups = [idx]
    else:
        groups = clusters(fused.location[idx], p.cluster_eps, p.min_points)
        groups = [idx[g] for g in groups]
    contacts = [_contact(fused, g) for g in groups]
    mass = [float(fused.likelihood[g].sum()) for g in groups]
    out = [c for c, m in zip(contacts, mass, strict=True) if m >= p.min_mass]
    out.sort(key=lambda c: -c.likelihood)
    return out


def clusters(points: np.ndarray, eps: float, min_points: int = 1) -> list[np.ndarray]:
    """Euclidean clusters (open3d DBSCAN); indices into ``points``, noise left out."""
    if points.shape[0] == 0:
        return []
    o3d = open3d_backend.load()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, dtype=np.float64)))
    labels = np.asarray(pcd.cluster_dbscan(eps=eps, min_points=min_points, print_progress=False))
    if labels.size == 0 or labels.max() < 0:
        return []
    order = np.argsort(labels, kind="stable")
    sorted_labels = labels[order]
    starts = np.searchsorted(sorted_labels, np.arange(labels.max() + 1))
    ends = np.searchsorted(sorted_labels, np.arange(labels.max() + 1), side="right")
    return [order[s:e] for s, e in zip(starts, ends, strict=True) if e > s]
