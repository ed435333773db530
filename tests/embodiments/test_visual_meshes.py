"""Robots' visual meshes decimated for rendering: the copies keep the shape, are written once, and a rendered frame stays the same."""

from __future__ import annotations

import os

import numpy as np
import pytest

from contactflow.embodiments.sensors.render_camera import render_available
from contactflow.embodiments.urdf_compose import erd_file
from contactflow.embodiments.visual_meshes import decimated

# a world without a Vulkan device draws nothing (its cameras cast rays): it has no visual meshes to decimate
needs_render = pytest.mark.skipif(not render_available(), reason="no Vulkan device: nothing is rendered")


def _mesh(path: str) -> tuple[np.ndarray, int]:
    import sapien

    parts = sapien.render.RenderShapeTriangleMesh(path).parts
    return np.concatenate([p.get_vertices() for p in parts]), sum(len(p.get_triangles()) for p in parts)


@needs_render
def test_a_decimated_visual_mesh_keeps_its_shape_and_is_written_once(tmp_path, monkeypatch):
    import sapien

    monkeypatch.setenv("CONTACTFLOW_CACHE", str(tmp_path))
    sapien.render.RenderSystem()  # the loader reads meshes for a render device
    src = str(erd_file("panda_description/meshes/visual/link6.dae"))
    copy = decimated([src], 2000)[src]
    assert copy.endswith(".ply") and copy.startswith(str(tmp_path / "meshes"))
    (v0, n0), (v1, n1) = _mesh(src), _mesh(copy)
    assert n0 > 20_000 and n1 <= 2000
    assert np.allclose(v0.min(0), v1.min(0), atol=0.002) and np.allclose(v0.max(0), v1.max(0), atol=0.002)
    written = os.stat(copy).st_mtime_ns
    assert decimated([src], 2000)[src] == copy and os.stat(copy).st_mtime_ns == written  # the cache's copy, not written again
    small = str(erd_file("allegro_hand_description/meshes/link_13.0.STL"))
    assert _mesh(small)[1] <= 2000 and decimated([small], 2000) == {small: small}  # drawn as it is, and known to be
    assert decimated([small, src], 2000) == {small: small, src: copy}
    assert len(list((tmp_path / "meshes").glob("*.ply"))) == 1 and len(list((tmp_path / "meshes").glob("*.whole"))) == 1
    other = decimated([src], 500)[src]
    assert other != copy and _mesh(other)[1] <= 500  # another bound, another copy


@needs_render
def test_a_depth_frame_with_decimated_robot_meshes_is_the_same_off_the_robot_and_within_a_millimetre_on_it():
    from contactflow.embodiments.sim_robot import SimRobot
    from contactflow.embodiments.world import World, WorldParams
    from contactflow.recognition.bench_vision import ROBOT, table_objects

    frames = {}
    for triangles in (0, 2000):
        world = World(WorldParams(visual_triangles=triangles))
        world.add_table()
        for spec in table_objects():
            world.add_object(spec)
        robot = SimRobot(world, ROBOT)
        robot.step(0.3)
        frames[triangles] = robot.camera("kinect")
    objects = {s.name for s in table_objects()} | {"table", "ground"}

    def on_robot(frame) -> np.ndarray:
        ids = [i for i, name in enumerate(frame.label_names) if name not in objects]
        return np.isin(frame.labels, ids)

    whole, light = frames[0], frames[2000]
    r0, r1 = on_robot(whole), on_robot(light)
    assert r0.sum() > 20_000  # the arms are in the Kinect's view
    assert (r0 != r1).sum() < 0.005 * r0.sum()  # the robot's silhouette moves by a few edge pixels
    off = ~r0 & ~r1
    assert np.array_equal(whole.depth[off], light.depth[off])
    both = r0 & r1 & (whole.depth > 0) & (light.depth > 0)
    assert np.percentile(np.abs(whole.depth[both] - light.depth[both]), 99) < 0.002


def test_a_negative_or_fractional_triangle_bound_is_refused_naming_the_param():
    from contactflow.embodiments.world import World, WorldError, WorldParams

    for bad in (-1, 2.5):
        with pytest.raises(WorldError, match=r"WorldParams.visual_triangles .* is not a count >= 0"):
            World(WorldParams(visual_triangles=bad))
