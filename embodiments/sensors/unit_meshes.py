"""open3d's meshes of PhysX's primitive collision shapes at unit size, stored in ``unit_meshes.npz``.

Every world meshes its robots' hands at start (the hand points of a robot's description), and a
box, sphere or cylinder is its unit mesh scaled: exactly the vertices open3d makes at that size.
Stored, they spare a world the import of open3d (0.75 s of the 2 s it takes to start) when it
ray casts no camera. ``python -m contactflow.embodiments.sensors.unit_meshes`` writes the file
again from open3d; a test checks that it still matches.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

PATH = Path(__file__).with_name("unit_meshes.npz")
SPHERES = (8, 12)  # resolutions the camera's meshes use
CYLINDERS = (16, 24)

Mesh = tuple[np.ndarray, np.ndarray]  # vertices (n, 3) float64, triangles (m, 3) int64


def generate() -> dict[str, np.ndarray]:
    """The unit meshes, made by open3d: a unit cube from the origin, unit-radius spheres, cylinders of radius
    and height 1 about z."""
    from contactflow.recognition import open3d_backend

    mesh = open3d_backend.load().geometry.TriangleMesh
    made = {"box": mesh.create_box(1.0, 1.0, 1.0)}
    made |= {f"sphere{r}": mesh.create_sphere(1.0, resolution=r) for r in SPHERES}
    made |= {f"cylinder{r}": mesh.create_cylinder(1.0, 1.0, resolution=r) for r in CYLINDERS}
    return {f"{name}_{part}": np.asarray(getattr(m, part), dtype=np.float64 if part == "vertices" else np.int64)
            for name, m in made.items() for part in ("vertices", "triangles")}


@functools.cache
def _stored() -> dict[str, np.ndarray]:
    with np.load(PATH) as data:
        return {k: data[k] for k in data.files}


def _scaled(name: str, scale: np.ndarray) -> Mesh:
    stored = _stored()
    return stored[f"{name}_vertices"] * scale, stored[f"{name}_triangles"].copy()


def box(size: np.ndarray) -> Mesh:
    """A box of ``size`` (3,) m from the origin, as open3d's ``create_box``."""
    return _scaled("box", np.asarray(size, dtype=np.float64))


def sphere(radius: float, resolution: int) -> Mesh:
    """A sphere about the origin, as open3d's ``create_sphere``."""
    return _scaled(f"sphere{resolution}", np.full(3, float(radius)))


def cylinder(radius: float, height: float, resolution: int) -> Mesh:
    """A cylinder about z, centred on the origin, as open3d's ``create_cylinder``."""
    return _scaled(f"cylinder{resolution}", np.array([radius, radius, height], dtype=np.float64))


def merged(*meshes: Mesh) -> Mesh:
    """One mesh of several, as open3d's ``+``: vertices in order, each mesh's triangles renumbered after the last's."""
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes[:-1]])
    return np.vstack([v for v, _ in meshes]), np.vstack([t + o for (_, t), o in zip(meshes, offsets, strict=True)])


if __name__ == "__main__":
    np.savez(PATH, **generate())
