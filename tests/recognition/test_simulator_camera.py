"""The pipeline on the simulator's camera, with the robot's spherical model as self filter."""

from __future__ import annotations

from contactflow.recognition.bench_vision import simulated_frames
from contactflow.recognition.pipeline import SegmentationPipeline


def test_simulator_frame_gives_one_cluster_per_object_and_none_on_the_robot():
    fr = simulated_frames()
    with_filter = SegmentationPipeline().process_depth(fr.depths[0], fr.K, fr.pose, 0.0, fr.distance)
    without = SegmentationPipeline().process_depth(fr.depths[0], fr.K, fr.pose, 0.0)
    assert with_filter.plane is not None and abs(with_filter.plane.offset + 0.75) < 0.01
    assert len(with_filter.clusters) == fr.objects == 5
    assert len(without.clusters) > 5  # the arms at home reach into the region of interest
    for c in with_filter.clusters:
        assert fr.distance(c.points).min() > 0.015
        assert 0.75 < c.centroid[2] < 0.95
