"""Spherical robot model (App. B): eq. B.2-B.3 distances and a model that covers the robot's geometry."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.spherical import SphericalModel, Stope, fit_bisphere, slab_bispheres
from contactflow.embodiments.testing import make_robot


def _model(c1, c2, r1, r2) -> SphericalModel:
    m = SphericalModel([Stope("l", 0, np.array(c1, float), np.array(c2, float), r1, r2)], np.eye(4))
    return m


def test_sphere_distance_eq_b2():
    m = _model([0, 0, 0], [0, 0, 0], 0.1, 0.1)
    assert m.distance(np.array([[0.3, 0.0, 0.0], [0.0, 0.05, 0.0]])) == pytest.approx([0.2, -0.05])


def test_bisphere_distance_eq_b3_clamps_lambda():
    m = _model([0, 0, 0], [1, 0, 0], 0.1, 0.2)
    pts = np.array([[-0.5, 0.0, 0.0],  # lambda < 0: first sphere
                    [0.5, 0.5, 0.0],  # lambda = 0.5: radius 0.15
                    [1.5, 0.0, 0.0]])  # lambda > 1: second sphere
    assert m.distance(pts) == pytest.approx([0.4, 0.35, 0.3])


def test_fit_contains_every_point():
    rng = np.random.default_rng(0)
    pts = rng.uniform([-0.2, -0.03, -0.02], [0.2, 0.03, 0.02], (500, 3))
    c1, c2, r1, r2 = fit_bisphere(pts)
    m = _model(c1, c2, r1, r2)
    assert m.distance(pts).max() <= 1e-9
    assert max(r1, r2) < 0.06  # not a single big sphere


def test_a_flat_box_is_slabs_that_hug_its_broad_faces_where_one_bisphere_is_a_ball_around_it():
    half = np.array([0.0205, 0.0565, 0.0475])  # the allegro palm: a 4 cm plate
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    slabs = slab_bispheres(corners)
    assert len(slabs) == 3 and all(r1 == r2 <= half[0] * np.sqrt(2) for _, _, r1, r2 in slabs)
    model = SphericalModel([Stope("palm", 0, c1, c2, r1, r2) for c1, c2, r1, r2 in slabs], np.eye(4))
    inside = np.random.default_rng(0).uniform(-half, half, (2000, 3))
    assert model.distance(np.vstack([inside, corners])).max() <= 1e-9  # the box is covered
    off_face = np.array([[half[0] + 0.01, y, z] for y in (-0.03, 0.0, 0.03) for z in (-0.03, 0.0, 0.03)])
    assert model.distance(off_face).min() > 0.0  # 1 cm off its broad face is outside
    ball = _model(*fit_bisphere(corners))
    assert ball.distance(off_face).max() < -0.02  # one bi-sphere: 2 cm and more inside


def test_the_allegro_palm_is_three_slabs_and_its_fingers_one_bisphere_a_link():
    robot = make_robot("tombatossals")
    links = robot.spherical.links
    assert links.count("right_palm_link") == 3 and links.count("right_link_2.0") == 1
    assert robot.spherical.r1[links.index("right_palm_link")] < 0.03  # the ball around the palm had 7.3 cm


@pytest.mark.parametrize("name", ["tombatossals", "melfa"])
def test_model_covers_the_robot_seen_by_the_camera(name):
    robot = make_robot(name)
    model = robot.spherical
    assert len(model.stopes) >= 8
    kin = robot.kin
    # sample the robot's own collision surfaces: each link origin is inside, points far away are outside
    origins = np.stack([kin.frame_pose(s.link)[:3, 3] for s in model.stopes])
    assert np.all(model.distance(origins) < 0.0)
    far = np.array([[2.0, 2.0, 2.0], [0.8, 0.0, 0.76]])
    assert np.all(model.distance(far) > 0.05)
    pts = np.random.default_rng(0).uniform([0.0, -0.5, 0.7], [0.8, 0.5, 1.4], (200, 3))
    d, link = model.distance(pts, return_link=True)
    for i in range(0, 200, 20):
        per_stope = [_model(model.C1[m], model.C2[m], model.r1[m], model.r2[m]).distance(pts[i][None])[0]
                     for m in range(len(model.stopes))]
        assert d[i] == pytest.approx(min(per_stope))
        assert link[i] == int(np.argmin(per_stope))


def test_self_filter_of_the_camera_cloud():
    robot = make_robot("tombatossals")
    frame = robot.camera("kinect")
    names = np.array(frame.label_names)
    pixels, points = frame.pixels[::4], frame.points[::4]
    hit = names[frame.labels[pixels[:, 0], pixels[:, 1]]]
    on_robot = np.char.find(hit.astype(str), "left_") >= 0
    on_robot |= np.char.find(hit.astype(str), "right_") >= 0
    assert on_robot.sum() > 500
    d = robot.spherical.distance(points)
    assert np.mean(d[on_robot] < 0.01) > 0.99  # robot points are inside the model
    table = hit == "table"
    assert np.mean(d[table] > 0.01) > 0.95  # the table mostly is not


@pytest.mark.parametrize("margin", [0.0, 0.01, 0.05])
def test_clear_of_is_the_distance_beyond_the_margin_for_points_near_and_far_from_the_robot(margin):
    robot = make_robot("tombatossals")
    model = robot.spherical
    rng = np.random.default_rng(1)
    # the camera's points (most far from every link, some on the arms and hands) and points around the s-topes
    near = model.C1[rng.integers(len(model.C1), size=3000)] + rng.normal(0.0, 0.04, (3000, 3))
    pts = np.vstack([robot.camera("kinect").points[::7], near])
    d = model.distance(pts)
    assert (d <= margin).sum() > 500 and (d > margin).sum() > 500
    assert np.array_equal(model.clear_of(pts, margin), d > margin)
    assert model.clear_of(np.zeros((0, 3)), margin).shape == (0,)
