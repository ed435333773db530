"""Tactile pressure arrays from the physics contact points on the pads, spread with a Gaussian.

PhysX reports at most ~4 points per shape pair, at the corners of the contact patch, so
binning them would light 3-4 taxels. On flat pads, the points of one contact pair that
span an area are treated as a patch: its total normal force is spread evenly over the
taxels whose centres lie inside the patch (a flat face pressed on the pad loads the whole
overlap, as on a real pressure array). Isolated points, and every point on curved
fingertip pads (unrolled on their sphere), are spread with a Gaussian of width ``sigma``
(normalised over the plane, so a contact at the edge loses the part outside the pad).
"""

from __future__ import annotations

import functools

import numpy as np

from contactflow.embodiments.registry import HandSpec, PadSpec
from contactflow.embodiments.transforms import pose_to_matrix


def _frozen(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    for a in arrays:
        a.setflags(write=False)  # shared by every sample of the pad: nobody may change them
    return arrays


@functools.cache
def _pad_axes(pad: PadSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pad's normal and surface axes (once per pad: a sample with contacts asked for them per contact)."""
    n = np.asarray(pad.normal, dtype=np.float64)
    n /= np.linalg.norm(n)
    u = np.asarray(pad.u_axis, dtype=np.float64)
    u = u - n * (u @ n)
    u /= np.linalg.norm(u)
    return _frozen(n, u, np.cross(n, u))


@functools.cache
def taxel_grid(pad: PadSpec) -> tuple[np.ndarray, np.ndarray]:
    """Taxel centres in pad surface coordinates: u (cols) and v (rows), each (rows, cols)."""
    du, dv = pad.size[0] / pad.cols, pad.size[1] / pad.rows
    u = (np.arange(pad.cols) - (pad.cols - 1) / 2) * du
    v = (np.arange(pad.rows) - (pad.rows - 1) / 2) * dv
    return _frozen(*np.meshgrid(u, v))


def taxel_positions(pad: PadSpec) -> np.ndarray:
    """Taxel centres in the link frame, (rows, cols, 3)."""
    n, u, v = _pad_axes(pad)
    gu, gv = taxel_grid(pad)
    o = np.asarray(pad.origin, dtype=np.float64)
    if pad.radius <= 0:
        return o + gu[..., None] * u + gv[..., None] * v
    c = o - pad.radius * n
    au, av = gu / pad.radius, gv / pad.radius
    # inverse of surface_coords: tan(angle) = tangential / normal component
    d = n + np.tan(au)[..., None] * u + np.tan(av)[..., None] * v
    return c + pad.radius * d / np.linalg.norm(d, axis=-1, keepdims=True)


def surface_coords(pad: PadSpec, p_local: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, normal offset) of points in the link frame, on the (unrolled) pad surface."""
    n, u, v = _pad_axes(pad)
    o = np.asarray(pad.origin, dtype=np.float64)
    if pad.radius <= 0:
        d = p_local - o
        return d @ u, d @ v, d @ n
    c = o - pad.radius * n
    d = p_local - c
    dn, du, dv = d @ n, d @ u, d @ v
    r = np.linalg.norm(d, axis=-1)
    return pad.radius * np.arctan2(du, dn), pad.radius * np.arctan2(dv, dn), np.where(dn > 0, r - pad.radius, np.inf)


def pressure(pad: PadSpec, p_local: np.ndarray, force: np.ndarray) -> np.ndarray:
    """Pressure image (rows, cols) in N per taxel for contact points ``p_local`` (K, 3) with normal forces (K,)."""
    out = np.zeros((pad.rows, pad.cols))
    if len(p_local) == 0:
        return out
    cu, cv, off = surface_coords(pad, p_local)
    du, dv = pad.size[0] / pad.cols, pad.size[1] / pad.rows
    margin = 2 * pad.sigma
    ok = (np.abs(off) <= pad.range_) & (np.abs(cu) <= pad.size[0] / 2 + margin) & (np.abs(cv) <= pad.size[1] / 2 + margin)
    if not ok.any():
        return out
    gu, gv = taxel_grid(pad)
    d2 = (gu[None] - cu[ok, None, None]) ** 2 + (gv[None] - cv[ok, None, None]) ** 2
    w = np.exp(-d2 / (2 * pad.sigma**2)) * (du * dv) / (2 * np.pi * pad.sigma**2)
    return np.tensordot(force[ok], w, axes=1)


def patch_pressure(pad: PadSpec, p_local: np.ndarray, force: np.ndarray) -> np.ndarray | None:
    """Pressure of one flat contact patch (its corner points), or None if it covers no taxel centre."""
    if pad.radius > 0 or len(p_local) < 3:
        return None
    cu, cv, off = surface_coords(pad, p_local)
    ok = np.abs(off) <= pad.range_
    if ok.sum() < 3:
        return None
    pts = np.stack([cu[ok], cv[ok]], 1)
    centred = pts - pts.mean(0)
    if np.linalg.svd(centred, compute_uv=False)[-1] < 1e-4:
        return None  # the points lie on a line: an edge contact, not a patch
    from scipy.spatial import ConvexHull

    # the hull's facet half-planes: a taxel centre is covered when it is on the inner side of all
    facets = ConvexHull(pts).equations
    gu, gv = taxel_grid(pad)
    grid = np.stack([gu.ravel(), gv.ravel()], 1)
    inside = (grid @ facets[:, :2].T + facets[:, 2] <= 1e-9).all(axis=1)
    if not inside.any():
        return None
    out = np.zeros(gu.size)
    out[inside] = force[ok].sum() / inside.sum()
    return out.reshape(gu.shape)


class TactileSensor:
    """All pads of one hand; ``read(contacts, dt)`` returns ``{pad name: (rows, cols)}``."""

    def __init__(self, art, hand: HandSpec) -> None:
        self.art, self.hand = art, hand
        self.pads = hand.pads
        self._link_of = {p.name: art.links[p.link] for p in self.pads}
        self.bodies = {id(art.links[p.link]) for p in self.pads}  # what World.contacts_of selects on
        self.lost = False
        self._last: tuple[float, dict[str, np.ndarray]] | None = None

    @property
    def stamp(self) -> float:
        """Time of the latest sample (-inf before the first): what a stream watchdog checks."""
        return self._last[0] if self._last is not None else -np.inf

    def sample(self, t: float, contacts: list, dt: float) -> dict[str, np.ndarray]:
        """The arrays at time ``t`` (one sample per time stamp); a lost stream repeats its last sample."""
        if self.lost:
            if self._last is None:
                return {p.name: np.zeros((p.rows, p.cols)) for p in self.pads}
            return {k: v.copy() for k, v in self._last[1].items()}
        if self._last is None or self._last[0] != t:
            self._last = (t, self.read(contacts, dt))
        return {k: v.copy() for k, v in self._last[1].items()}

    def read(self, contacts: list, dt: float) -> dict[str, np.ndarray]:
        groups: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        for c in contacts:
            b0, b1 = c.bodies
            k0, k1 = id(b0), id(b1)
            key = k0 if k0 in self.bodies else (k1 if k1 in self.bodies else None)
            if key is None or not c.points:
                continue
            P = np.array([p.position for p in c.points], dtype=np.float64)
            F = np.array([np.linalg.norm(p.impulse) for p in c.points], dtype=np.float64) / dt
            groups.setdefault(key, []).append((P, F))
        out = {}
        for pad in self.pads:
            link = self._link_of[pad.name]
            img = np.zeros((pad.rows, pad.cols))
            if id(link) in groups:
                T = pose_to_matrix(link.get_entity_pose())
                for P, F in groups[id(link)]:
                    if F.sum() <= 0:
                        continue
                    local = (P - T[:3, 3]) @ T[:3, :3]
                    patch = patch_pressure(pad, local, F)
                    img += patch if patch is not None else pressure(pad, local, F)
            out[pad.name] = img
        return out
