"""Approach vectors of known shapes and their filters."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.recognition.grasp_synthesis import (
    ApproachVector,
    collision_filter,
    distance_filter,
    model_approach_vectors,
    orientation_filter,
    pca_approach_vectors,
    reachability_filter,
    register_model,
)
from contactflow.recognition.pipeline import detect_plane
from contactflow.recognition.synthetic import box_mesh

SIZE = np.array([0.20, 0.10, 0.05])
YAW = 0.5
CENTER = np.array([0.5, 0.1, 0.3])


def _axes():
    c, s = np.cos(YAW), np.sin(YAW)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_pca_approach_vectors_of_a_box_are_along_its_axes():
    import open3d as o3d

    o3d.utility.random.seed(0)
    pts = np.asarray(box_mesh(tuple(SIZE), CENTER, YAW).sample_points_uniformly(8000).points)
    avs = pca_approach_vectors(pts)
    assert len(avs) == 6
    R = _axes()
    for i in range(3):
        for sign in (1, -1):
            expected_dir = -sign * R[:, i]
            match = [a for a in avs if a.direction @ expected_dir > 0.995]
            assert len(match) == 1, (i, sign)
            # starts on the face centre where the axis leaves the box
            assert np.linalg.norm(match[0].position - (CENTER + sign * R[:, i] * SIZE[i] / 2)) < 0.006


def test_pca_with_standoff_and_too_few_points():
    import open3d as o3d

    o3d.utility.random.seed(1)
    pts = np.asarray(box_mesh(tuple(SIZE), CENTER, YAW).sample_points_uniformly(4000).points)
    near = pca_approach_vectors(pts)
    far = pca_approach_vectors(pts, standoff=0.05)
    for a, b in zip(near, far, strict=True):
        assert np.allclose(b.position - a.position, -0.05 * a.direction, atol=1e-9)
    assert pca_approach_vectors(np.zeros((0, 3))) == []
    assert pca_approach_vectors(np.full((20, 3), np.nan)) == []


def test_model_approach_vectors_point_against_the_surface_normals():
    mesh = box_mesh(tuple(SIZE), (0, 0, 0))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = _axes(), CENTER
    avs = model_approach_vectors(mesh, T, spacing=0.02)
    assert len(avs) > 50
    R = _axes()
    for a in avs:
        # every direction is one of the six inward face normals
        assert np.max(np.abs(R.T @ a.direction)) > 0.999
        loc = R.T @ (a.position - CENTER)
        k = int(np.argmax(np.abs(R.T @ a.direction)))
        assert abs(abs(loc[k]) - SIZE[k] / 2) < 1e-3


def test_icp_registers_a_shifted_model():
    import open3d as o3d

    o3d.utility.random.seed(2)
    model = np.asarray(box_mesh(tuple(SIZE), (0, 0, 0)).sample_points_uniformly(3000).points)
    T = np.eye(4)
    T[:3, :3] = _axes()
    T[:3, 3] = CENTER
    cloud = model @ T[:3, :3].T + T[:3, 3]
    init = np.eye(4)
    init[:3, :3] = _axes() @ np.array([[np.cos(0.1), -np.sin(0.1), 0], [np.sin(0.1), np.cos(0.1), 0], [0, 0, 1]])
    init[:3, 3] = CENTER + 0.01
    est, fitness, rmse = register_model(model, cloud, init)
    assert fitness > 0.95 and rmse < 0.005
    assert np.allclose(est[:3, 3], CENTER, atol=0.005)


def _avs():
    z = np.array([0, 0, 1.0])
    return [
        ApproachVector(np.array([0.5, 0, 0.3]), -z),  # from above
        ApproachVector(np.array([0.4, 0, 0.1]), np.array([1.0, 0, 0])),  # from the side, low
        ApproachVector(np.array([1.5, 0, 0.1]), np.array([-1.0, 0, 0])),  # far
    ]


def test_orientation_and_distance_filters():
    avs = _avs()
    down = orientation_filter(avs, np.array([0, 0, -1.0]), 10)
    assert len(down) == 1 and down[0] is avs[0]
    assert len(orientation_filter(avs, np.array([0, 0, -1.0]), 91)) == 3
    near = distance_filter(avs, np.zeros(3), 1.0)
    assert [a for a in avs if a in near] == avs[:2]


def test_reachability_filter_uses_the_ik_callable():
    avs = _avs()
    calls = []

    def ik(T):
        calls.append(T)
        return np.zeros(7) if np.linalg.norm(T[:3, 3]) < 1.0 else None

    kept = reachability_filter(avs, ik)
    assert kept == avs[:2] and len(calls) == 3
    assert all(np.allclose(c[:3, 2], a.direction) for c, a in zip(calls, avs, strict=True))


def test_collision_filter_rejects_hands_in_the_table_or_obstacles():
    rng = np.random.default_rng(0)
    table = np.column_stack((rng.uniform(0, 1, 3000), rng.uniform(-0.5, 0.5, 3000), np.zeros(3000)))
    plane, _ = detect_plane(table)
    avs = _avs()
    kept = collision_filter(avs, plane=plane)
    assert avs[0] in kept and avs[1] in kept
    low = ApproachVector(np.array([0.4, 0, 0.02]), np.array([1.0, 0, 0]))
    assert collision_filter([low], plane=plane) == []
    wall = np.column_stack((np.full(500, 0.3), rng.uniform(-0.1, 0.1, 500), rng.uniform(0, 0.3, 500)))
    assert avs[1] not in collision_filter(avs, obstacles=wall, plane=plane)
    assert collision_filter([], plane=plane) == []


def test_grasp_generator_service_filters_through_the_plane_and_orientation():
    from contactflow.nodes.testing import FakeIO, run_module
    from contactflow.recognition.messages import PlaneMsg, SegmentedObjects
    from contactflow.recognition.pipeline import SegmentationPipeline
    from contactflow.recognition.services.grasp_generator import GraspGenerator
    from contactflow.recognition.testing import three_objects

    s = three_objects()
    res = SegmentationPipeline().process_depth(s.render(), s.K, s.pose)
    objs, plane = SegmentedObjects.of(res.clusters), PlaneMsg.of(res.plane)

    def run(params, ik=None):
        io = FakeIO()
        io.feed("objects", objs)
        io.feed("plane", plane)
        run_module(GraspGenerator("grasps", params, ik), io, steps=1)
        return io.published["approach_vectors"][-1]

    avs = run(GraspGenerator.Params())
    dirs, pos = avs.directions.numpy(), avs.positions.numpy()
    assert 3 <= len(dirs) <= 5
    assert not np.any(dirs[:, 2] > 0.9)  # nothing from under the table
    assert np.all(pos[:, 2] > 0.0)
    top = run(GraspGenerator.Params(direction=(0.0, 0.0, -1.0), max_angle_deg=10.0))
    assert len(top.directions.numpy()) == 1
    assert top.positions.numpy()[0, 2] > res.clusters[0].box.extent[2]
    assert len(run(GraspGenerator.Params(), ik=lambda T: None).directions.numpy()) == 0


def test_grasp_generator_reachability_uses_the_configured_arm_ik():
    from contactflow.nodes.testing import FakeIO, run_module
    from contactflow.recognition.messages import PlaneMsg, SegmentedObjects
    from contactflow.recognition.pipeline import SegmentationPipeline
    from contactflow.recognition.services.grasp_generator import GraspGenerator
    from contactflow.recognition.testing import three_objects

    s = three_objects()
    res = SegmentationPipeline().process_depth(s.render(), s.K, s.pose)
    objs, plane = SegmentedObjects.of(res.clusters), PlaneMsg.of(res.plane)
    target = int(np.argmin([c.centroid[1] for c in res.clusters]))  # the box on the right arm's side

    def dirs(**kw):
        io = FakeIO()
        io.feed("objects", objs)
        io.feed("plane", plane)
        run_module(GraspGenerator("grasps", GraspGenerator.Params(index=target, **kw)), io, steps=1)
        return io.published["approach_vectors"][-1].directions.numpy()

    def has(d, v):
        return bool(np.any(d @ np.asarray(v, float) > 0.99))

    free = dirs()
    # the scene's table top is z = 0, where tombatossals' torso base stands (as on its 0.75 m table)
    right = dirs(robot="tombatossals", arm="right", base=(0.0,) * 6)
    assert has(free, (-1, 0, 0)) and not has(right, (-1, 0, 0))  # from beyond the box: out of reach
    assert has(right, (0, 0, -1)) and 1 <= len(right) < len(free)
    assert len(dirs(robot="tombatossals", arm="right", base=(2.5, 0, 0, 0, 0, 0))) == 0  # robot 2.5 m away
    with pytest.raises(ValueError, match="params.robot"):
        dirs(robot="no_such_robot")
    with pytest.raises(ValueError, match="params.base"):
        dirs(robot="tombatossals", base=(0.0, 0.0))
