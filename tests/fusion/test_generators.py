"""Each generator core on synthetic inputs with a known answer."""

import numpy as np
import pytest

from contactflow.fusion.condensation import condense
from contactflow.fusion.generators.finger import FingerPoseGenerator
from contactflow.fusion.generators.force_torque import (
    ForceTorqueParams,
    ft_hypotheses,
    wrench_lines,
)
from contactflow.fusion.generators.motion import MotionSupportGenerator, predict, support_cloud
from contactflow.fusion.generators.null import NullGenerator, NullParams
from contactflow.fusion.generators.range import RangeGenerator, RangeParams, segment_object
from contactflow.fusion.generators.simulator import SimulatorParams, sample_poses, simulator_support
from contactflow.fusion.generators.tactile import tactile_hypotheses
from contactflow.fusion.geometry import capsule_distance, distance_fn, interior_points
from contactflow.fusion.hypotheses import Hypotheses, HypothesisType, voxelize
from contactflow.fusion.integrator import Integrator


def hand_caps(T):
    """A hand as a bi-sphere along the sensor z axis, posed by T."""
    local = np.array([[0, 0, 0.05], [0, 0, 0.15]])
    w = local @ T[:3, :3].T + T[:3, 3]
    return np.array([[*w[0], 0.04, *w[1], 0.04]])


def pose(rz=0.0, t=(0.5, 0.2, 0.9)):
    c, s = np.cos(rz), np.sin(rz)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = t
    return T


def test_capsule_distance_eq_b2_b3():
    caps = np.array([[0, 0, 0, 0.1, 1, 0, 0, 0.2]])
    pts = np.array([[0.5, 0.5, 0], [-1, 0, 0], [2, 0, 0], [0.5, 0, 0]])
    d = capsule_distance(pts, caps)
    assert d == pytest.approx([0.5 - 0.15, 0.9, 0.8, -0.15])


def test_tactile_eq_4_6():
    taxels = np.array([[0, 0, 0], [0.02, 0, 0], [0.04, 0, 0], [0.06, 0, 0]], float)
    h = tactile_hypotheses(np.array([0.0, 2.0, 4.0, 1.0]), taxels, 1.5, normals=np.tile([0, 0, 1.0], (4, 1)))
    assert len(h) == 3 and h.stamp == 1.5
    order = np.argsort(h.location[:, 0])
    assert h.likelihood[order] == pytest.approx([0.5, 1.0, 0.25])
    assert h.force[order] == pytest.approx([2.0, 4.0, 1.0])
    assert np.allclose(h.direction, [0, 0, -1])
    assert (h.kind == HypothesisType.REGULAR).all()
    assert len(tactile_hypotheses(np.zeros(4), taxels, 0.0)) == 0
    with pytest.raises(ValueError, match="3 taxel positions"):
        tactile_hypotheses(np.ones(4), taxels[:3], 0.0)


def test_wrench_lines_pass_through_the_application_point():
    d_true = np.array([0.03, -0.02, 0.1])
    f = np.array([-2.0, 1.0, 3.0])
    pts = wrench_lines(f, np.cross(d_true, f), np.full(3, -0.2), np.full(3, 0.3), 0.001, 0.1)
    assert pts.shape[0] > 100
    assert np.allclose(np.cross(pts, f), np.cross(d_true, f), atol=1e-9)  # every point is on the line
    assert np.linalg.norm(pts - d_true, axis=1).min() < 0.001


@pytest.mark.parametrize("rz", [0.0, 1.0])
def test_force_torque_localises_contact_on_the_hand(rz):
    T = pose(rz)
    caps = hand_caps(T)
    p_local = np.array([0.04 * np.cos(0.3), 0.04 * np.sin(0.3), 0.1])  # on the hand surface
    f_local = np.array([-3.0, -0.5, 1.0])  # pushes into the hand
    h = ft_hypotheses(f_local, np.cross(p_local, f_local), T, distance_fn(caps), 2.0)
    p_world = T[:3, :3] @ p_local + T[:3, 3]
    assert len(h) >= 1 and h.likelihood.sum() == pytest.approx(1.0)
    assert np.allclose(h.likelihood, 1.0 / len(h))
    assert np.linalg.norm(h.location - p_world, axis=1).min() < 0.006
    assert np.allclose(h.direction[0], T[:3, :3] @ f_local / np.linalg.norm(f_local))
    integ = Integrator()
    integ.offer("ft", h, 2.0)
    (c,) = condense(integ.cycle(2.0))
    assert np.linalg.norm(c.location - p_world) < 0.015
    # Without the inward filter the exit point on the far side of the hand also survives.
    both = ft_hypotheses(f_local, np.cross(p_local, f_local), T, distance_fn(caps), 2.0,
                         ForceTorqueParams(inward_only=False))
    assert len(both) > len(h)


def test_force_torque_ignores_small_wrenches():
    T = pose()
    assert len(ft_hypotheses(np.array([0.3, 0, 0]), np.zeros(3), T, distance_fn(hand_caps(T)), 0.0)) == 0


def _box_points(c, cam, half=0.03, step=0.004):
    g = np.arange(-half, half + 1e-9, step)
    faces = []
    for ax in range(3):
        for s in (-1, 1):
            u, v = np.meshgrid(g, g, indexing="ij")
            p = np.zeros((u.size, 3))
            p[:, ax], p[:, (ax + 1) % 3], p[:, (ax + 2) % 3] = s * half, u.ravel(), v.ravel()
            n = np.zeros(3)
            n[ax] = s
            p = p + c
            faces.append(p[(cam - p) @ n > 0])
    return np.concatenate(faces)


def test_range_generator_finds_the_push_point():
    """A spherical hand pushes a box along +x: hypotheses appear on the box face it touches."""
    rng = np.random.default_rng(0)
    cam = np.array([0.0, 0.0, 1.4])
    params = RangeParams()
    gen = RangeGenerator(params)
    box = np.array([0.55, 0.0, 0.78])
    r = 0.03

    def caps(x):
        return np.array([[x, 0, 0.78, r, x, 0, 0.78, r]])

    hx = 0.46
    assert len(gen.observe(segment_object(_box_points(box, cam), None, params), distance_fn(caps(hx)), 0.0, cam)) == 0
    found = []
    for k in range(10):
        hx += 0.005
        if hx + r > box[0] - 0.03 + 1e-3:
            box = box + [0.005, 0, 0]
        dist = distance_fn(caps(hx))
        obj = segment_object(_box_points(box, cam) + rng.normal(0, 5e-4, 3), dist, params)
        h = gen.observe(obj, dist, 0.1 * k)
        if len(h):
            found.append((box[0] - 0.03, h))
    assert len(found) >= 3  # every frame of motion
    for face_x, h in found:
        assert h.likelihood.sum() == pytest.approx(1.0)
        centroid = h.location.mean(axis=0)
        assert np.linalg.norm(centroid - [face_x, 0, 0.78]) < 0.01


def test_range_static_object_gives_nothing():
    cam = np.array([0.0, 0.0, 1.4])
    params = RangeParams()
    gen = RangeGenerator(params)
    box = np.array([0.55, 0.0, 0.78])
    pts = _box_points(box, cam)
    far = distance_fn(np.array([[0.2, 0, 1.0, 0.03, 0.2, 0, 1.0, 0.03]]))
    gen.observe(pts, far, 0.0, cam)
    for k in range(3):
        assert len(gen.observe(pts, far, 0.1 * (k + 1))) == 0
    assert gen.grid is not None and (gen.grid.p == 1.0).any() and (gen.grid.p == 0.5).any()


def test_finger_pose_feedback():
    gen = FingerPoseGenerator([[0, 1], [2, 3]])
    surfaces = {0: np.array([[0.0, 0, 0], [0.01, 0, 0]]), 1: np.array([[0.0, 0.05, 0], [0.0, 0.06, 0]])}
    q = np.zeros(4)
    assert len(gen.update(q, surfaces.__getitem__, 0.0)) == 0  # takes the reference
    assert len(gen.update(q + 0.01, surfaces.__getitem__, 0.1)) == 0  # below threshold
    bent = q.copy()
    bent[3] = 0.2
    h = gen.update(bent, surfaces.__getitem__, 0.2)
    assert len(h) == 2 and h.likelihood == pytest.approx([0.5, 0.5])
    assert (h.location[:, 1] > 0.04).all()  # on finger 1 only
    assert len(gen.update(bent, surfaces.__getitem__, 0.3, actuated=True)) == 0
    assert len(gen.update(bent, surfaces.__getitem__, 0.4)) == 0  # new reference after actuation
    # a hand whose command ended still settles: no reference while its joints move, then one once they are still
    gen.update(q, surfaces.__getitem__, 0.5, actuated=True)
    assert len(gen.update(q + 0.02, surfaces.__getitem__, 0.6)) == 0 and gen.reference is None
    assert len(gen.update(q + 0.04, surfaces.__getitem__, 0.7)) == 0 and gen.reference is None
    assert len(gen.update(q + 0.042, surfaces.__getitem__, 0.8)) == 0 and gen.reference == pytest.approx(q + 0.042)
    assert len(gen.update(q + 0.042 + bent, surfaces.__getitem__, 0.9)) == 2  # bent from where it came to rest


def test_motion_support_eq_4_12_4_13():
    assert np.allclose(predict(np.array([1.0, 2.0]), np.array([0.5, 2.5])), [1.5, 1.5])
    gen = MotionSupportGenerator()
    seen = []

    def surface_at(q):
        seen.append(q.copy())
        return np.array([[q[0], 0.0, 0.0]])

    assert len(gen.update(np.array([0.10]), surface_at, 0.0)) == 0
    h = gen.update(np.array([0.12]), surface_at, 0.1)
    assert np.allclose(seen[-1], [0.14])
    assert h.likelihood == pytest.approx([0.3]) and h.kind[0] == HypothesisType.SUPPORT
    assert abs(h.location[0, 0] - 0.14) <= 0.0025 + 1e-9


def test_motion_support_cloud_is_the_voxelized_surface_one_hypothesis_per_voxel():
    # points several to a voxel, as the surfaces of neighbouring links overlap
    pts = np.random.default_rng(0).uniform(-0.05, 0.05, (5000, 3)) + [0.5, -0.3, 0.9]
    got = support_cloud(pts, 0.3, 0.005, 2.0)
    want = voxelize(Hypotheses.make(pts, 0.3, HypothesisType.SUPPORT, stamp=2.0), 0.005, reduce="max")
    assert 0 < len(got) < len(pts) and got.stamp == want.stamp == 2.0
    for field in ("location", "likelihood", "kind", "force", "direction"):
        assert np.array_equal(getattr(got, field), getattr(want, field)), field


def test_simulator_support_and_pose_sampling():
    h = simulator_support([np.array([[0.5, 0, 0.8]]), np.array([[0.5, 0, 0.8], [0.6, 0, 0.8]])], 1.0)
    assert len(h) == 2 and np.allclose(h.likelihood, 0.5) and (h.kind == HypothesisType.SUPPORT).all()
    d = simulator_support(np.array([[0.5, 0, 0.8]]), 1.0, SimulatorParams(dilate=0.01))
    assert len(d) > 20 and np.linalg.norm(d.location - [0.5, 0, 0.8], axis=1).max() < 0.016
    poses = sample_poses(np.eye(4), 0.02, 500, np.random.default_rng(0))
    assert poses.shape == (500, 4, 4) and abs(poses[:, :3, 3].std() - 0.02) < 0.003


def test_a_robot_at_rest_gets_the_null_clouds_it_would_get_were_each_computed_afresh():
    # a hand that moved and then holds still: its points come as the same array (the shell's memo), so the
    # generator reuses its cloud once everything swept before has expired; fresh copies never are reused
    caps = np.array([[0.5, 0, 0.8, 0.03, 0.5, 0, 0.8, 0.03]])
    before, after = (interior_points(c, 0.005, 0.01) for c in (caps, caps + [0.1, 0, 0, 0, 0.1, 0, 0, 0]))
    reused, fresh = (NullGenerator(NullParams(margin=0.01, memory=0.25)) for _ in range(2))
    reused.update(before, 0.0)
    fresh.update(before.copy(), 0.0)
    sizes = []
    for k in range(1, 12):
        t = 0.05 * k
        a, b = reused.update(after, t), fresh.update(after.copy(), t)
        assert np.array_equal(a.location, b.location) and a.stamp == b.stamp == t, t
        sizes.append(len(a))
    assert sizes[0] > sizes[-1] == len(after)  # both positions, then only where the hand rests
    reused.update(before, 0.65)  # it moves back: both again
    assert len(reused.update(before, 0.7)) > len(after)


def test_null_generator_swept_space_and_free_boxes():
    gen = NullGenerator(NullParams(margin=0.01, memory=0.5), free_boxes=[(np.array([1.0, 1, 1]), np.array([1.02, 1.02, 1.02]))])
    caps = np.array([[0.5, 0, 0.8, 0.03, 0.5, 0, 0.8, 0.03]])
    inside = interior_points(caps, 0.005, 0.01)
    assert (capsule_distance(inside, caps) < -0.01).all()
    h = gen.update(inside, 0.0)
    assert (h.kind == HypothesisType.NULL).all()
    assert len(h) == len(inside) + 64
    moved = caps.copy()
    moved[0, [0, 4]] += 0.1
    h2 = gen.update(interior_points(moved, 0.005, 0.01), 0.3)
    assert len(h2) > len(h)  # both positions swept
    h3 = gen.update(None, 1.0)
    assert len(h3) == 64  # swept space forgotten, free box stays
    # A surface hypothesis is never vetoed by the swept space.
    integ = Integrator()
    integ.offer("null", gen.update(inside, 1.1), 1.1)
    integ.offer("tactile", tactile_hypotheses(np.array([1.0]), np.array([[0.53, 0, 0.8]]), 1.1), 1.1)
    assert len(integ.cycle(1.1)) == 1


def test_a_distance_with_a_cutoff_is_exact_near_the_parts_and_infinite_beyond():
    """What the range generator evaluates over its grid: a point within the cutoff of a part gets its exact signed
    distance, one farther than that from every part +inf (no distance to each part computed for it)."""
    rng = np.random.default_rng(3)
    c1 = rng.uniform(0.3, 0.7, (12, 3))
    r = rng.uniform(0.01, 0.04, (12, 2))
    caps = np.concatenate([c1, r[:, :1], c1 + rng.normal(0, 0.05, (12, 3)), r[:, 1:]], axis=1)
    pts = rng.uniform(0.0, 1.0, (40_000, 3))
    exact = distance_fn(caps)(pts)
    cut = distance_fn(caps, cutoff=0.01)(pts)
    near = exact <= 0.01
    assert near.sum() > 100 and (~near).sum() > 100
    assert np.array_equal(cut[near], exact[near])
    assert np.all(cut[~near] > 0.01) and np.isinf(cut[exact > 0.2]).all()
