"""The pipeline on the simulator's camera, with the robot's spherical model as self filter."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.recognition.bench_vision import simulated_frames
from contactflow.recognition.pipeline import SegmentationPipeline


@pytest.fixture(scope="module")
def fr():
    return simulated_frames()


def test_simulator_frame_gives_one_cluster_per_object_and_none_on_the_robot(fr):
    with_filter = SegmentationPipeline().process_depth(fr.depths[0], fr.K, fr.pose, 0.0, fr.distance)
    without = SegmentationPipeline().process_depth(fr.depths[0], fr.K, fr.pose, 0.0)
    assert with_filter.plane is not None and abs(with_filter.plane.offset + 0.75) < 0.01
    assert len(with_filter.clusters) == fr.objects == 5
    assert len(without.clusters) > 5  # the arm reaching over the table is in the region of interest
    for c in with_filter.clusters:
        assert fr.distance(c.points).min() > 0.015
        assert 0.75 < c.centroid[2] < 0.95


def test_self_filter_service_poses_the_robot_model_from_joint_states(fr):
    from contactflow.embodiments.messages import JointState
    from contactflow.nodes.testing import FakeIO, run_module
    from contactflow.recognition.messages import PointCloud, nd
    from contactflow.recognition.pipeline import roi_filter
    from contactflow.recognition.services.self_filter import SelfFilter

    pipe = SegmentationPipeline()
    res = pipe.process_depth(fr.depths[0], fr.K, fr.pose)
    inside = roi_filter(pipe.cloud(fr.depths[0], fr.K, fr.pose), res.roi)
    names, q = fr.joints
    io = FakeIO()
    io.feed("cloud", PointCloud.of(inside))
    io.feed("joints", JointState(robot="tombatossals", names=names, position=nd(q), velocity=nd(np.zeros_like(q)),
                                 effort=nd(np.zeros_like(q))))
    run_module(SelfFilter("self", SelfFilter.Params(robot="tombatossals")), io, steps=1)
    kept = io.published["cloud"][-1].xyz()
    expected = inside[fr.distance(inside) >= 0.02]
    assert len(kept) < len(inside)
    # the same points as the simulator's own posed model removes, up to float32 rounding
    assert abs(len(kept) - len(expected)) <= 0.01 * len(inside)
