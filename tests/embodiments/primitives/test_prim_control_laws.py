"""The thesis control laws (eq. 3.1-3.6) and helpers as pure functions, plus the catalog."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.primitives.base import Primitive, PrimitiveError, matrix6, pose6
from contactflow.embodiments.primitives.catalog import CATALOG
from contactflow.embodiments.primitives.place import place_velocity
from contactflow.embodiments.primitives.place_location import free_spot
from contactflow.embodiments.primitives.release import release_velocity
from contactflow.embodiments.primitives.robust_grasp import alignment_velocity, sliding_velocity
from contactflow.embodiments.primitives.slide import slide_velocity
from contactflow.embodiments.primitives.transport import (
    force_field,
    limit_velocity,
    transport_velocity,
)
from contactflow.nodes.registry import resolve
from contactflow.nodes.taskgraph import KNOWN_PRIMITIVES


def test_catalog_names_resolve_to_primitives() -> None:
    assert set(CATALOG) == set(KNOWN_PRIMITIVES)
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
