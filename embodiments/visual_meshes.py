"""Robots' visual meshes decimated for rendering, written once to the cache beside the composed URDFs.

Why: lavapipe renders a depth frame in time that follows the triangles it draws, not the pixels.
The bench-vision cell has 310k triangles, most of them the Panda arms' visual meshes (14-22k per
link). Its Kinect's 640x480 depth frame took 24.0 ms, and 8.7 ms with the bodies over 2,000
triangles hidden. A copy of each mesh, its parts' seams welded and then reduced by quadric
decimation (open3d), draws the same depth off the robot and within a millimetre on it (p99),
which the vision chain's self filter, with its 1-2 cm margin, never sees. Colours and materials
are dropped: the shader packs draw positions and body labels only. The copies are made in a
process of their own (``python -m contactflow.embodiments.visual_meshes``): a world never imports
open3d.
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import subprocess
import sys
from collections.abc import Sequence

import numpy as np

from contactflow.embodiments.urdf_compose import cache_dir

MAX_TRIANGLES = 2000  # per mesh file drawn; a file with fewer is drawn as it is
_FORMAT = 2
"""Bumped when the written copies change for the same source (invalidates the cache)."""
_TIMEOUT = 300.0  # s for the process that writes a robot's copies (~1 s for tombatossals' 50 meshes)


def _paths(filename: str, max_triangles: int) -> tuple[pathlib.Path, pathlib.Path]:
    """(the copy of ``filename``, the marker that says it needs none) in the cache."""
    src = pathlib.Path(filename)
    st = src.stat()
    key = hashlib.sha1(f"{src.resolve()}:{st.st_size}:{st.st_mtime_ns}:{max_triangles}:{_FORMAT}".encode()).hexdigest()
    copy = cache_dir("meshes") / f"{src.stem}-{key[:12]}.ply"
    return copy, copy.with_suffix(".whole")


def decimated(filenames: Sequence[str], max_triangles: int = MAX_TRIANGLES) -> dict[str, str]:
    """For each mesh file, one with its shape and at most ``max_triangles`` triangles: the file itself when it has no
    more, else its copy (PLY) in the cache, written at the first call by one process for all of them."""
    paths = {f: _paths(f, max_triangles) for f in set(filenames)}  # a stat and a hash each, once

    def known(f: str) -> str | None:
        copy, whole = paths[f]
        return str(copy) if copy.exists() else f if whole.exists() else None

    todo = sorted({f for f in filenames if known(f) is None})
    if todo:
        run = subprocess.run([sys.executable, "-m", __name__, str(max_triangles), *todo], capture_output=True,
                             text=True, timeout=_TIMEOUT)
        if run.returncode != 0:
            raise OSError(f"visual meshes: decimating {len(todo)} file(s), {todo[0]} first, failed: {run.stderr[-1500:]}")
    out = {f: known(f) for f in filenames}
    missing = [f for f, path in out.items() if path is None]
    if missing:
        raise OSError(f"visual meshes: no copy of {missing[0]} was written")
    return out  # type: ignore[return-value]


def _write(filename: str, max_triangles: int) -> None:
    """Write the copy of ``filename`` (or the marker that it needs none); a render device must exist (the mesh is read
    by SAPIEN's loader, which reads Collada, STL and OBJ alike)."""
    import open3d as o3d
    import sapien

    copy, whole = _paths(filename, max_triangles)
    parts = sapien.render.RenderShapeTriangleMesh(filename).parts
    counts = np.cumsum([0] + [len(p.get_vertices()) for p in parts])
    triangles = np.concatenate([p.get_triangles().astype(np.int64) + counts[k] for k, p in enumerate(parts)])
    if len(triangles) <= max_triangles:
        whole.touch()
        return
    vertices = np.concatenate([p.get_vertices() for p in parts]).astype(np.float64)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    # the parts' seams welded first: a mesh in pieces loses whole pieces to the decimation (12 % of the arms' pixels)
    mesh = mesh.merge_close_vertices(1e-6).remove_duplicated_triangles().remove_degenerate_triangles()
    mesh = mesh.simplify_quadric_decimation(max_triangles)
    tmp = copy.with_name(f"{copy.name}.tmp{os.getpid()}.ply")
    if not o3d.io.write_triangle_mesh(str(tmp), mesh):
        raise OSError(f"visual mesh {filename}: could not write its decimated copy {tmp}")
    tmp.replace(copy)


if __name__ == "__main__":
    import sapien

    sapien.render.RenderSystem()
    for name in sys.argv[2:]:
        _write(name, int(sys.argv[1]))
