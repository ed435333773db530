"""V4 curvedness and shape classes, LOC features."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.recognition.features import (
    FEATURES,
    aos_activation,
    object_features,
    sos_activation,
)
from contactflow.recognition.geometry import intrinsics
from contactflow.recognition.pipeline import SegmentationPipeline
from contactflow.recognition.shape import (
    BOX,
    CYLINDER,
    SPHERE,
    UNKNOWN,
    ShapeClassifier,
    curvedness,
    object_mask,
    silhouette_contour,
)
from contactflow.recognition.synthetic import (
    Scene,
    box_mesh,
    cylinder_mesh,
    orbit_pose,
    sphere_mesh,
)
from contactflow.recognition.testing import three_objects


def _curvedness(mesh, elevation, azimuth=35.0):
    depth = Scene([mesh]).render(intrinsics(), orbit_pose(np.zeros(3), 0.7, elevation, azimuth), 640, 480)
    return curvedness(silhouette_contour(np.isfinite(depth)))


def test_curvedness_orders_box_cylinder_sphere():
    box = _curvedness(box_mesh((0.08, 0.08, 0.08)), 40)
    cyl = _curvedness(cylinder_mesh(0.05, 0.1), 40)
    sph = _curvedness(sphere_mesh(0.05), 40)
    assert box < 0.1 < 0.3 < cyl < 0.9 < sph


def test_curvedness_of_drawn_shapes():
    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    circle = np.column_stack((100 + 60 * np.cos(t), 100 + 60 * np.sin(t)))
    square = np.vstack([np.column_stack((np.linspace(0, 100, 100, endpoint=False), np.zeros(100))),
                        np.column_stack((np.full(100, 100.0), np.linspace(0, 100, 100, endpoint=False))),
                        np.column_stack((np.linspace(100, 0, 100, endpoint=False), np.full(100, 100.0))),
                        np.column_stack((np.zeros(100), np.linspace(100, 0, 100, endpoint=False)))])
    assert curvedness(circle) > 0.95
    assert curvedness(square) < 0.01
    assert np.isnan(curvedness(np.zeros((0, 2))))
    assert np.isnan(curvedness(np.full((20, 2), np.nan)))
    assert silhouette_contour(np.zeros((10, 10), bool)).shape == (0, 2)


def _trained():
    return ShapeClassifier().fit(np.array([0.0, 0.02, 0.04, 0.5, 0.6, 0.4, 0.98, 1.0]),
                                 [BOX, BOX, BOX, CYLINDER, CYLINDER, CYLINDER, SPHERE, SPHERE])


def test_membership_follows_eq_8_3_and_8_4():
    clf = _trained()
    mu, sd = clf.stats()
    c = 0.3
    m = sd / np.abs(c - mu)
    assert np.allclose(clf.probabilities(c), m / m.sum())
    assert np.isclose(clf.probabilities(0.02).sum(), 1.0)


def test_seventy_percent_rule_and_box_cylinder_rule():
    clf = _trained()
    assert clf.classify(0.02)[0] == BOX
    assert clf.classify(0.5)[0] == CYLINDER
    assert clf.classify(0.99)[0] == SPHERE
    # between box and cylinder: neither reaches 70 %, together they do → cylinder
    label, p = clf.classify(0.1)
    assert p.max() < 0.7 and p[0] + p[1] >= 0.7 and label == CYLINDER
    # between cylinder and sphere: no rule applies → unknown
    label, p = clf.classify(0.935)
    assert p.max() < 0.7 and label == UNKNOWN
    assert clf.classify(float("nan"))[0] == UNKNOWN
    with pytest.raises(ValueError, match="no training samples"):
        ShapeClassifier().classify(0.5)


def test_object_mask_is_the_silhouette_of_a_segmented_object():
    s = three_objects()
    depth = s.render()
    res = SegmentationPipeline().process_depth(depth, s.K, s.pose)
    masks = [object_mask(depth, s.K, s.pose, c.box) for c in res.clusters]
    assert all(m.sum() > 200 for m in masks)
    assert not np.any(masks[0] & masks[1])
    assert not object_mask(np.full((48, 64), np.nan), s.K, s.pose, res.clusters[0].box).any()


def test_sos_aos_equations():
    d1, d2, d3 = 200.0, 100.0, 50.0
    sos = 1 - ((d1 - d2) / (d1 + d2)) ** 2 - 0.03 * d3 / (d1 + d2) - 0.5 / (1 + np.exp(-0.04 * (d3 - 150)))
    aos = 1 - (d1 - d2) / (d1 + d2) - 0.37 * d1 / d3 - 0.5 / (1 + np.exp(-0.04 * (d1 - 150)))
    assert np.isclose(sos_activation(d1, d2, d3), sos)
    assert np.isclose(aos_activation(d3, d1, d2), aos)  # order does not matter
    f = object_features(np.array([0.05, 0.2, 0.1]), 3.0)
    assert np.allclose(f, [sos, aos, 200, 100, 50, 3.0])
    assert len(f) == len(FEATURES)
    assert np.isnan(object_features(np.array([0.0, 0.1, 0.1]))).all()
