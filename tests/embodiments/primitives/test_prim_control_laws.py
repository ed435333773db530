"""The thesis control laws (eq. 3.1-3.6) and helpers as pure functions, plus the catalog."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from contactflow.embodiments.primitives.base import (
    Primitive,
    PrimitiveError,
    matrix6,
    pose6,
    top_grasp_pose,
    wall_yaws,
)
from contactflow.embodiments.primitives.catalog import CATALOG
from contactflow.embodiments.primitives.place import place_speed, place_velocity
from contactflow.embodiments.primitives.place_location import free_spot
from contactflow.embodiments.primitives.release import release_velocity
from contactflow.embodiments.primitives.robust_grasp import (
    alignment_velocity,
    levelled_pose,
    look_pose,
    search_poses,
    sliding_velocity,
)
from contactflow.embodiments.primitives.slide import slide_velocity
from contactflow.embodiments.primitives.transport import (
    force_field,
    limit_velocity,
    transport_velocity,
)
from contactflow.nodes.module import Layer
from contactflow.nodes.registry import layer_types, resolve


def test_catalog_names_resolve_to_primitives() -> None:
    assert set(CATALOG) <= layer_types(Layer.PRIMITIVE)  # what task files may name
    for name in CATALOG:
        assert issubclass(resolve(name), Primitive), name


def test_alignment_eq_3_1() -> None:
    v, done = alignment_velocity(0.0, False, 0.1, 0.005, 0.005, 0.04)
    assert not done and v[2] == pytest.approx(0.04)
    v, done = alignment_velocity(0.3, True, 0.1, 0.005, 0.005, 0.04)
    assert not done and v[0] > 0 and v[2] < 0
    v, done = alignment_velocity(-0.3, True, 0.1, 0.005, 0.005, 0.04)
    assert not done and v[0] < 0 and v[2] < 0
    _, done = alignment_velocity(0.05, True, 0.1, 0.005, 0.005, 0.04)
    assert done


def test_sliding_eq_3_2() -> None:
    assert sliding_velocity(-3.0, 2.0, 0.005) == -0.005
    assert sliding_velocity(3.0, 2.0, 0.005) == 0.005
    assert sliding_velocity(1.0, 2.0, 0.005) == 0.0


def test_transport_eq_3_3_and_limits() -> None:
    err = np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert transport_velocity(err, 1.0, np.zeros(3), 15.0)[0] == pytest.approx(0.1)
    assert not transport_velocity(err, 1.0, np.array([0.0, 0.0, 20.0]), 15.0).any()
    v = limit_velocity(np.array([0.4, 0.2, 0.0, 0.0, 0.0, 0.0]), np.array([0.1, 0.1, 0.1, 0.5, 0.0, 0.0]))
    assert v[0] == pytest.approx(0.1) and v[1] == pytest.approx(0.05)  # normalised, direction kept
    locked = limit_velocity(np.array([0.0, 0.0, 0.0, 0.2, 0.2, 0.0]), np.array([0.1, 0.1, 0.1, 0.0, 0.0, 0.5]))
    assert locked[3] == 0.0 and locked[4] == 0.0
    push = force_field(np.array([0.0, 0.0, 0.0]), np.array([[0.05, 0.0, 0.0]]), 0.1, 1e-3)
    assert push[0] < 0  # away from the obstacle point
    assert not force_field(np.zeros(3), np.array([[0.5, 0.0, 0.0]]), 0.1, 1e-3).any()


def test_place_release_slide_eqs() -> None:
    n = np.array([0.0, 0.0, 1.0])
    assert place_velocity(np.zeros(3), n, 0.005, 5.0)[2] == -0.005
    assert not place_velocity(np.array([0.0, 0.0, 6.0]), n, 0.005, 5.0).any()
    # told where the object rests: fast until slow_distance above it, the thesis's velocity from there
    assert place_speed(0.10, 0.005, 0.05, 0.04) == 0.05
    assert place_speed(0.04, 0.005, 0.05, 0.04) == place_speed(-0.01, 0.005, 0.05, 0.04) == 0.005
    assert place_speed(None, 0.005, 0.05, 0.04) == 0.005  # not told: eq. 3.4 all the way
    assert place_speed(0.10, 0.005, 0.001, 0.04) == 0.005  # never slower than velocity
    assert release_velocity(np.array([0.0, 0.0, 6.0]), n, 0.001, 5.0)[2] == 0.001
    assert not release_velocity(np.array([0.0, 0.0, 2.0]), n, 0.001, 5.0).any()
    to = np.array([0.1, 0.0, 0.0])
    assert slide_velocity(2.0, to, n, 5.0, 9.0, 0.005, 0.005)[2] < 0  # press
    assert slide_velocity(10.0, to, n, 5.0, 9.0, 0.005, 0.005)[2] > 0  # loosen
    assert slide_velocity(7.0, to, n, 5.0, 9.0, 0.005, 0.005)[0] == pytest.approx(0.005)


def test_pose_helpers_and_free_spot() -> None:
    T = matrix6((0.1, 0.2, 0.3, 0.1, -0.2, 0.3), "t")
    v = pose6(T)
    assert np.allclose(matrix6(tuple(v[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")), "t"), T)
    with pytest.raises(PrimitiveError, match="params.target"):
        matrix6((1.0, 2.0), "move.params.target")
    spot = free_spot(np.array([[0.5, 0.0]]), np.array([0.4, -0.1, 0.6, 0.1]), 0.05)
    assert spot is not None and np.linalg.norm(spot - [0.5, 0.0]) >= 0.05
    assert free_spot(np.array([[0.5, 0.0]]), np.array([0.49, -0.01, 0.51, 0.01]), 0.05) is None


def _top_grasp(tilt_deg: tuple[float, float, float]) -> np.ndarray:
    """A hand pointing its z axis down (top grasp), turned by roll, pitch, yaw in its own frame."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("x", np.pi).as_matrix() @ Rotation.from_euler("xyz", tilt_deg, degrees=True).as_matrix()
    T[:3, 3] = (0.5, -0.3, 0.9)
    return T


def test_levelling_turns_a_tilted_top_grasp_down_about_the_pivot_and_keeps_its_yaw() -> None:
    z = np.array([0.0, 0.0, 1.0])
    pivot = np.array([-0.055, 0.015, 0.0])
    T = _top_grasp((10.0, -12.0, 30.0))
    levelled = levelled_pose(T, z, pivot, tolerance=0.4)
    assert levelled is not None
    goal, turn = levelled
    assert turn == pytest.approx(np.arccos(-(T[:3, :3] @ z)[2]))
    assert np.allclose(goal[:3, :3] @ z, (0.0, 0.0, -1.0), atol=1e-9)
    assert np.allclose(goal[:3, :3] @ pivot + goal[:3, 3], T[:3, :3] @ pivot + T[:3, 3], atol=1e-9)
    # the yaw survives: the hand x axis keeps its heading in the horizontal plane (within the tilt)
    hx0, hx1 = T[:2, 0] / np.linalg.norm(T[:2, 0]), goal[:2, 0] / np.linalg.norm(goal[:2, 0])
    assert float(hx0 @ hx1) > np.cos(np.deg2rad(8.0))
    assert levelled_pose(_top_grasp((0.0, 0.0, 30.0)), z, pivot, 0.4) is None  # already down
    assert levelled_pose(_top_grasp((40.0, 0.0, 0.0)), z, pivot, 0.4) is None  # not a top grasp
    assert levelled_pose(T, z, pivot, 0.0) is None  # off (the thesis)


def test_search_backs_out_along_the_approach_then_goes_over_the_offset() -> None:
    z = np.array([0.0, 0.0, 1.0])
    x = np.array([1.0, 0.0, 0.0])
    T0 = _top_grasp((0.0, 0.0, 90.0))
    now = T0.copy()
    now[:3, 3] += (0.01, 0.02, -0.12)  # descended 12 cm and drifted while closing
    back, over = search_poses(T0, now, z, x, (0.09, -0.08))
    assert np.allclose(back[:3, 3], (0.51, -0.28, 0.9))  # straight up, no sideways drag
    assert np.allclose(over[:3, :3], T0[:3, :3])
    shift = T0[:3, :3].T @ (over[:3, 3] - T0[:3, 3])
    assert np.allclose(shift, (0.09, -0.08, 0.0))


def _box_points(lo, hi, step=0.005) -> np.ndarray:
    """The surface points of the box [lo, hi] (a stand-in for a depth camera's cloud of it, seen all round)."""
    axes = [np.arange(a, b + 1e-9, step) for a, b in zip(lo, hi, strict=True)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    on = np.any(np.isclose(g, lo) | np.isclose(g, hi), axis=1)
    return g[on]


def test_a_look_goes_over_the_top_of_the_object_nearest_to_where_the_grasp_began() -> None:
    rng = np.random.default_rng(0)
    table = np.column_stack([rng.uniform(0.2, 0.9, 40000), rng.uniform(-0.6, 0.1, 40000), np.full(40000, 0.75)])
    near = _box_points((0.60, -0.36, 0.75), (0.66, -0.30, 0.80))  # pushed 10 cm from where the grasp began
    far = _box_points((0.30, 0.0, 0.75), (0.36, 0.06, 0.80))  # another object, 40 cm off
    T0 = _top_grasp((0.0, 0.0, 90.0))
    pivot = np.array([-0.055, 0.015, 0.0])
    g = T0[:3, :3] @ pivot + T0[:3, 3]
    goal, d = look_pose(np.vstack([table, near, far]), T0, pivot, radius=0.2)
    assert np.allclose(goal[:3, :3], T0[:3, :3]) and goal[2, 3] == pytest.approx(T0[2, 3])  # same height and turn
    moved = goal[:3, :3] @ pivot + goal[:3, 3]
    assert moved[:2] == pytest.approx((0.63, -0.33), abs=0.003)  # the pivot over the box's top centre
    assert d == pytest.approx(float(np.linalg.norm(np.array([0.63, -0.33]) - g[:2])), abs=0.003)
    # nothing within the radius (the far box is beyond it), or nothing on the table: no pose
    assert look_pose(np.vstack([table, far]), T0, pivot, radius=0.2) is None
    assert look_pose(table, T0, pivot, radius=0.2) is None


def test_wall_yaws_turn_the_hand_side_measured_for_walls_toward_the_nearest_wall() -> None:
    walls = (0.4, -0.5, 0.7, -0.14)  # [xmin, ymin, xmax, ymax]
    yaws = [np.pi / 2, np.pi, 0.0]
    assert wall_yaws(yaws, (0.55, -0.32), walls, 0.055, (0.0, -1.0)) == yaws  # far from every wall
    assert wall_yaws(yaws, (0.68, -0.32), (), 0.055, (0.0, -1.0)) == yaws  # no walls given
    assert wall_yaws(yaws, (0.68, -0.32), walls, 0.0, (0.0, -1.0)) == yaws  # margin 0: off
    for xy, outward in (((0.68, -0.32), (1, 0)), ((0.42, -0.32), (-1, 0)), ((0.55, -0.48), (0, -1)),
                        ((0.55, -0.16), (0, 1)), ((0.67, -0.48), (0, -1))):  # the last: a corner, the -y wall is nearer
        got = wall_yaws(yaws, xy, walls, 0.055, (0.0, -1.0))
        hand = top_grasp_pose((xy[0], xy[1], 0.8), got[0])
        assert hand[:3, :3] @ np.array([0.0, -1.0, 0.0]) == pytest.approx([*outward, 0.0], abs=1e-9), xy
        others = [a for a in yaws if not np.isclose(np.cos(a - got[0]), 1.0)]
        assert got[1:] == others  # the given yaws follow in their order, without the one put first
