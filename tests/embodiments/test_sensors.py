"""Sensors from the physics: F/T reads m·g, tactile only under contact, camera cloud of a known box, encoders."""

from __future__ import annotations

import os
import subprocess

import numpy as np
import pytest

from contactflow.embodiments import world as world_module
from contactflow.embodiments.registry import CameraSpec, PadSpec
from contactflow.embodiments.sensors.camera import DepthCamera, depth_to_points
from contactflow.embodiments.sensors.render_camera import render_available
from contactflow.embodiments.sensors.tactile import pressure, taxel_positions
from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.testing import make_robot, melfa_around_plate
from contactflow.embodiments.world import World, WorldError, WorldParams, box
from contactflow.nodes.status import Event, Status

MASS = 0.5


@pytest.fixture(scope="module")
def grasp():
    """melfa picks a 0.5 kg box: (robot, tactile while open, tactile while holding)."""
    robot = melfa_around_plate(MASS)
    open_tactile = robot.tactile("gripper")
    lift_the_plate(robot)
    return robot, open_tactile, robot.tactile("gripper")


def lift_the_plate(robot) -> None:
    """melfa closes on the plate it stands around and lifts it to 0.95 m, then lets it settle 0.3 s."""
    arm, hand = robot.arm("arm"), robot.hand("gripper")
    hand.close()
    assert hand.wait(3.0) == Status.SUCCESS
    up = arm.ee_pose()
    up[2, 3] = 0.95
    arm.move_pose(up, speed=0.15)
    assert arm.wait(5.0) == Status.SUCCESS
    robot.step(0.3)


def test_ft_reads_the_held_weight(grasp):
    robot, _, _ = grasp
    assert robot.world.objects["obj"].pose()[2, 3] > 0.85  # lifted
    f = np.mean([robot.ft("arm").force for _ in range(1) if robot.step(0.01) is None], axis=0)
    assert f[2] == pytest.approx(-MASS * 9.81, rel=0.05)
    assert np.linalg.norm(f[:2]) < 0.05 * MASS * 9.81


def quiet(wrench: np.ndarray) -> bool:
    """A wrench within 5 sigma of the sensor's noise (FTSpec: 0.05 N, 0.005 N m per axis)."""
    return bool(np.linalg.norm(wrench[:3]) < 0.25 and np.linalg.norm(wrench[3:]) < 0.025)


def test_the_external_wrench_reads_the_load_whatever_was_tared_and_none_once_it_is_gone() -> None:
    # a primitive tares with the plate in hand (transport does): the tared reading then calls
    # the plate's loss a 5 N pull, the external one (the hand's own weight removed) an empty hand
    robot = melfa_around_plate(MASS)
    assert quiet(robot.ft("arm").external)  # the open hand beside the plate: nothing
    lift_the_plate(robot)
    robot.tare_ft("arm")
    robot.step(0.02)
    held = robot.ft("arm")
    assert np.linalg.norm(held.force) < 0.05 * MASS * 9.81
    assert held.external[2] == pytest.approx(-MASS * 9.81, rel=0.05)
    robot.world.remove_object("obj")
    robot.step(0.2)
    gone = robot.ft("arm")
    assert gone.force[2] == pytest.approx(MASS * 9.81, rel=0.05)
    assert quiet(gone.external)


def test_a_held_object_made_heavier_weighs_more_on_the_wrist_and_a_static_one_has_no_mass_to_set() -> None:
    # what the predictor does when a load mismatch teaches it an object's mass (thesis §5.7, model update)
    robot = melfa_around_plate(MASS)
    lift_the_plate(robot)
    plate = robot.world.objects["obj"]
    inertia = np.asarray(plate.body.get_inertia(), dtype=float)
    plate.set_mass(3 * MASS)
    robot.step(0.3)
    assert plate.mass() == pytest.approx(3 * MASS) and plate.pose()[2, 3] > 0.85  # still held
    assert np.asarray(plate.body.get_inertia()) == pytest.approx(3 * inertia)
    assert robot.ft("arm").external[2] == pytest.approx(-3 * MASS * 9.81, rel=0.05)
    table = next(o for o in robot.world.objects.values() if o.spec.static)
    with pytest.raises(WorldError, match="is static"):
        table.set_mass(1.0)
    with pytest.raises(WorldError, match="must be > 0"):
        plate.set_mass(0.0)


def test_the_external_wrench_of_an_empty_hand_stays_zero_as_the_wrist_turns() -> None:
    # the hand's weight pulls about the sensor differently in every pose: a tare holds for one
    robot = make_robot("tombatossals")
    arm = robot.arm("right")
    q = arm.q().copy()
    q[-2:] += (0.6, 1.0)
    arm.move_joints(q, speed=0.5)
    assert arm.wait(5.0) == Status.SUCCESS
    robot.step(0.3)
    turned = robot.ft("right")
    assert np.linalg.norm(turned.torque) > 0.1  # the boot tare no longer matches the hand's weight
    assert quiet(turned.external)


def test_tactile_shows_pressure_only_under_contact(grasp):
    _, open_tactile, held = grasp
    assert all(np.all(v == 0) for v in open_tactile.values())
    for pad in ("left", "right"):
        img = held[pad]
        assert img.shape == (5, 8)
        assert np.all(img >= 0)
        rows = img.sum(axis=1)
        assert rows[2] > 1.0  # the plate presses on the middle rows
        assert rows[0] == 0 and rows[4] == 0  # the outer rows, beside the plate, read nothing
    # the pads carry the grip force: equal and opposite on the two fingers
    assert held["left"].sum() == pytest.approx(held["right"].sum(), rel=0.1)


def test_removing_a_held_object_empties_the_pads_without_crashing() -> None:
    # the step's cached contacts pointed into the removed body: the next tactile read was a segfault
    robot = melfa_around_plate(0.1)
    hand = robot.hand("gripper")
    hand.close()
    assert hand.wait(3.0) == Status.SUCCESS
    robot.step(0.1)
    robot.world.step()  # a fresh physics step: its contacts are not read yet
    robot.world.remove_object("obj")
    assert all(np.all(v == 0) for v in robot.tactile("gripper").values())
    robot.step(0.05)
    assert all(np.all(v == 0) for v in robot.tactile("gripper").values())


def test_pressure_model_on_flat_and_curved_pads():
    flat = PadSpec("p", "l", origin=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), u_axis=(1.0, 0.0, 0.0), size=(0.016, 0.01))
    img = pressure(flat, np.array([[0.0, 0.0, 0.0]]), np.array([2.0]))
    r, c = np.unravel_index(img.argmax(), img.shape)
    assert r == 2 and c in (3, 4)
    assert img.sum() == pytest.approx(2.0, rel=0.1)
    assert np.all(pressure(flat, np.array([[0.05, 0.0, 0.0]]), np.array([2.0])) == 0)  # beside the pad
    assert np.all(pressure(flat, np.array([[0.0, 0.0, 0.02]]), np.array([2.0])) == 0)  # above it
    tip = PadSpec("t", "l", origin=(0.012, 0.0, 0.0), normal=(1.0, 0.0, 0.0), u_axis=(0.0, 0.0, 1.0), size=(0.022, 0.016),
                  radius=0.012)
    taxels = taxel_positions(tip)
    assert np.allclose(np.linalg.norm(taxels, axis=2), 0.012)
    front = pressure(tip, np.array([[0.012, 0.0, 0.0]]), np.array([1.0]))
    back = pressure(tip, np.array([[-0.012, 0.0, 0.0]]), np.array([1.0]))
    assert front.max() > 0 and np.all(back == 0)


TOP_DOWN = np.array([[0.0, -1.0, 0.0, 0.65], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 1.5], [0.0, 0.0, 0.0, 1.0]])
"""A camera 1.5 m above the floor over the table centre, looking straight down."""
BOX_SIZE, BOX_CENTRE = (0.1, 0.06, 0.08), np.array([0.55, 0.0, 0.79])
BACKENDS = ("render", "raycast") if render_available() else ("raycast",)


@pytest.fixture(scope="module")
def seen():
    """tombatossals looking at a known box on the table; one frame per camera backend (one shader compile)."""
    world = World(WorldParams(camera_backend="auto"))
    world.add_table()
    world.add_object(box("target", BOX_SIZE, tuple(BOX_CENTRE), mass=0.3))
    robot = SimRobot(world, "tombatossals")
    robot.step(0.1)
    spec = robot.spec.camera("kinect")
    cams = {b: DepthCamera(world, spec, robot.art.links[spec.link], backend=b) for b in BACKENDS}
    frames = {b: c.capture(robot.time) for b, c in cams.items()}
    return robot, cams, frames


def _box_top(points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    P = points
    near = P[(np.abs(P[:, 0] - centre[0]) < 0.08) & (np.abs(P[:, 1] - centre[1]) < 0.06) & (P[:, 2] > 0.755) & (P[:, 2] < 0.9)]
    return near[near[:, 2] > near[:, 2].max() - 0.003]


def _assert_box_top(top: np.ndarray, centre: np.ndarray) -> None:
    assert len(top) > 200
    assert top[:, 2].mean() == pytest.approx(centre[2] + BOX_SIZE[2] / 2, abs=5e-3)
    assert top[:, 0].min() == pytest.approx(centre[0] - BOX_SIZE[0] / 2, abs=5e-3)
    assert top[:, 0].max() == pytest.approx(centre[0] + BOX_SIZE[0] / 2, abs=5e-3)
    assert top[:, 1].min() == pytest.approx(centre[1] - BOX_SIZE[1] / 2, abs=5e-3)
    assert top[:, 1].max() == pytest.approx(centre[1] + BOX_SIZE[1] / 2, abs=5e-3)


@pytest.mark.parametrize("backend", BACKENDS)
def test_camera_cloud_of_a_known_box(seen, backend):
    robot, _, frames = seen
    frame = frames[backend]
    assert frame.depth.shape == (480, 640)
    assert np.allclose(depth_to_points(frame.depth, frame.K, frame.T_world_cam), frame.points, atol=1e-4)
    _assert_box_top(_box_top(frame.points, BOX_CENTRE), BOX_CENTRE)
    names = np.array(frame.label_names)
    hit = names[frame.labels[frame.pixels[:, 0], frame.pixels[:, 1]]]
    assert set(hit) >= {"table", "target"}
    gt = robot.ground_truth()
    assert np.allclose(gt.object_poses["target"][:3, 3], BOX_CENTRE, atol=2e-3)
    assert any({c.body_a, c.body_b} == {"target", "table"} for c in gt.contacts)


def test_the_camera_follows_a_moved_box(seen):
    robot, cams, _ = seen
    obj = robot.world.objects["target"]
    T = obj.pose()
    moved = T.copy()
    moved[:2, 3] += (0.05, -0.1)
    try:
        obj.set_pose(moved)
        for cam in cams.values():
            frame = cam.capture(robot.time)
            _assert_box_top(_box_top(frame.points, moved[:3, 3]), moved[:3, 3])
    finally:
        obj.set_pose(T)


def test_backends_agree_on_table_and_object_pixels(seen):
    robot, _, frames = seen
    assert robot.world.rendering == render_available()
    if not robot.world.rendering:
        assert robot.camera("kinect").labels.shape == (480, 640)
        return
    r, y = frames["render"], frames["raycast"]
    assert np.array_equal(r.K, y.K) and np.array_equal(r.T_world_cam, y.T_world_cam)
    rn, yn = np.array((*r.label_names, "")), np.array((*y.label_names, ""))
    r_hit, y_hit = rn[r.labels], yn[y.labels]
    for name in ("table", "target"):
        on_r, on_y = r_hit == name, y_hit == name
        both = on_r & on_y
        assert both.sum() > 0.99 * max(on_r.sum(), on_y.sum())  # the same pixels see it
        assert np.abs(r.depth[both] - y.depth[both]).max() < 3e-3
    # the robot's own camera renders (SimRobot builds its camera with the world's backend)
    own = robot.camera("kinect")
    assert np.abs(own.depth - r.depth)[(own.depth > 0) & (r.depth > 0)].max() < 1e-4
    own_hit = rn[own.labels].astype(str)
    on_robot = np.char.startswith(own_hit, "left_") | np.char.startswith(own_hit, "right_")
    assert on_robot.sum() > 1000  # the arms' URDF visuals are rendered


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_depth_read_is_the_full_frames_depth_and_keeps_the_stream_alive(seen, backend):
    robot, cams, _ = seen
    cam = cams[backend]
    t = robot.time + 1.0  # past the camera's period: a fresh read, not the cached frame
    depth, Twc = cam.read_depth(t)
    assert cam.stamp == t  # the stream's watchdog sees the read
    frame = cam.capture(t)
    assert np.array_equal(Twc, frame.T_world_cam) and depth.dtype == frame.depth.dtype == np.float32
    assert np.array_equal(depth, frame.depth)
    again, _ = cam.read_depth(t)  # within the period: the full frame's depth, not a new render
    assert again is frame.depth


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_frame_without_labels_is_the_labelled_frame_and_labels_asked_of_it_come_from_a_new_render(seen, backend):
    robot, cams, _ = seen
    cam = cams[backend]
    t = robot.time + 2.0  # past the camera's period: a fresh frame
    bare = cam.read(t, labels=False)
    assert cam.read(t, labels=False) is bare  # within the period: the same frame
    labelled = cam.read(t)  # labels asked of a frame taken without them: rendered again, with them
    assert cam.read(t) is labelled and cam.read(t, labels=False) is labelled
    assert np.array_equal(bare.depth, labelled.depth) and np.array_equal(bare.points, labelled.points)
    assert np.array_equal(bare.pixels, labelled.pixels)
    assert "target" in labelled.label_names and (labelled.labels >= 0).sum() == len(labelled.points)
    if backend == "render":
        assert labelled is not bare and bare.label_names == () and (bare.labels == -1).all()
    else:  # ray casting finds the labels on the way, asked for or not: the frame is not cast twice
        assert labelled is bare


def test_camera_backend_choice():
    assert World(WorldParams(camera_backend="raycast")).rendering is False
    with pytest.raises(WorldError, match="camera_backend 'laser'"):
        World(WorldParams(camera_backend="laser"))
    world = World(WorldParams(camera_backend="raycast"))
    with pytest.raises(ValueError, match="backend 'render' needs a world"):
        DepthCamera(world, CameraSpec("c", ""), T_world_cam=np.eye(4), backend="render")
    assert DepthCamera(world, CameraSpec("c", ""), T_world_cam=np.eye(4)).backend == "raycast"


def test_without_a_vulkan_device_auto_ray_casts_and_render_is_refused(monkeypatch):
    monkeypatch.setattr(world_module, "render_available", lambda: False)
    world = World(WorldParams(camera_backend="auto"))
    assert world.rendering is False
    world.add_table()
    frame = DepthCamera(world, CameraSpec("c", ""), T_world_cam=TOP_DOWN).capture(0.0)
    assert frame.depth[240, 320] == pytest.approx(1.5 - 0.75, abs=1e-4)  # the table top, 1.5 m camera height
    with pytest.raises(WorldError, match="no Vulkan device"):
        World(WorldParams(camera_backend="render"))


def test_encoders_follow_the_fingers(melfa):
    hand = melfa.hand("gripper")
    hand.set_fingers(np.array([0.02]))
    assert hand.wait(2.0) == Status.SUCCESS
    assert melfa.finger_positions("gripper")[0] == pytest.approx(0.02, abs=1e-3)
    hand.open()
    assert hand.wait(2.0) == Status.SUCCESS


def test_baxter_estimated_wrench_detects_table_contact():
    robot = make_robot("baxter")
    arm = robot.arm("left")
    quiet = np.array([robot.ft("left").force for _ in range(20) if robot.step(0.01) is None])
    assert quiet.std(axis=0).max() > 0.3  # noisy, as the real virtual sensor
    arm.guarded_move(np.array([0.0, 0.0, -0.05, 0.0, 0.0, 0.0]), max_force=8.0, duration=6.0)
    assert arm.wait(7.0) == Status.SUCCESS
    assert any(e == Event.CONTACT for _, e, _ in robot.events)
    assert arm.ee_pose()[2, 3] < 0.80  # stopped at the table (top at 0.75), not before


def test_allegro_fingertip_pad_feels_only_its_own_contact():
    robot = make_robot("tombatossals")
    arm = robot.arm("left")
    tip = robot.frame_pose("left_link_3.0_tip")[:3, 3]  # index fingertip, pad facing down at home
    robot.world.add_object(box("post", (0.03, 0.03, 0.1), (tip[0], tip[1], tip[2] - 0.07), static=True))
    arm.guarded_move(np.array([0.0, 0.0, -0.03, 0.0, 0.0, 0.0]), max_force=2.0, duration=5.0)
    assert arm.wait(6.0) == Status.SUCCESS
    robot.step(0.1)
    pads = robot.tactile("left_hand")
    index = pads["index"]
    assert index.max() > 0.05
    r, c = np.unravel_index(index.argmax(), index.shape)
    assert 1 <= r <= 3 and 2 <= c <= 5  # centred under the fingertip
    assert all(np.all(pads[p] == 0) for p in ("middle", "ring", "thumb"))
    assert all(np.all(v == 0) for v in robot.tactile("right_hand").values())


def test_wrench_control_presses_and_ft_matches_the_contact_force(melfa):
    arm = melfa.arm("arm")
    arm.guarded_move(np.array([0.0, 0.0, -0.05, 0.0, 0.0, 0.0]), max_force=3.0, duration=8.0)
    assert arm.wait(9.0) == Status.SUCCESS
    arm.set_wrench(np.array([0.0, 0.0, -10.0, 0.0, 0.0, 0.0]))  # press down with 10 N
    melfa.step(1.5)
    ft, table = [], []
    for _ in range(40):
        melfa.step(0.01)
        ft.append(melfa.ft("arm").force)
        table.append(sum(c.force * c.normal[2] for c in melfa.ground_truth().contacts if "table" in (c.body_a, c.body_b)))
    f = np.mean(ft, axis=0)
    assert f[2] == pytest.approx(10.0, rel=0.1)  # the F/T reads the table pushing up (+z)
    assert f[2] == pytest.approx(abs(np.mean(table)), rel=0.05)
    arm.move_joints(np.asarray(arm.home))
    assert arm.wait(6.0) == Status.SUCCESS


def test_the_stored_unit_meshes_are_open3d_s_and_mesh_every_primitive_shape_as_open3d_does():
    import open3d as o3d
    import sapien

    from contactflow.embodiments.sensors import unit_meshes
    from contactflow.embodiments.sensors.camera import shape_mesh

    made = unit_meshes.generate()
    assert made.keys() == unit_meshes._stored().keys()
    assert all(np.array_equal(made[k], unit_meshes._stored()[k]) for k in made)  # the file is open3d's, not stale
    mesh = o3d.geometry.TriangleMesh

    def o3d_along_x(m):  # PhysX's round shapes lie along x, open3d's along z
        return np.asarray(m.vertices)[:, [2, 1, 0]] * [1.0, 1.0, -1.0], np.asarray(m.triangles)[:, [0, 2, 1]]

    r, h = 0.013, 0.021
    capsule = mesh.create_cylinder(r, 2 * h, resolution=16)
    for z in (-h, h):
        capsule += mesh.create_sphere(r, resolution=8).translate((0.0, 0.0, z))
    material = sapien.physx.PhysxMaterial(1.0, 1.0, 0.0)
    cases = [(sapien.physx.PhysxCollisionShapeBox([0.01, 0.02, 0.03], material),
              (np.asarray(mesh.create_box(0.02, 0.04, 0.06).vertices) - [0.01, 0.02, 0.03],
               np.asarray(mesh.create_box(0.02, 0.04, 0.06).triangles))),
             (sapien.physx.PhysxCollisionShapeSphere(r, material),
              (np.asarray(mesh.create_sphere(r, resolution=12).vertices), np.asarray(mesh.create_sphere(r, resolution=12).triangles))),
             (sapien.physx.PhysxCollisionShapeCylinder(r, h, material), o3d_along_x(mesh.create_cylinder(r, 2 * h, resolution=24))),
             (sapien.physx.PhysxCollisionShapeCapsule(r, h, material), o3d_along_x(capsule))]
    for shape, (v, t) in cases:
        got_v, got_t = shape_mesh(shape)
        assert np.allclose(got_v, v, atol=1e-15) and np.array_equal(got_t, t), type(shape).__name__


def test_a_world_meshes_its_robots_hands_without_open3d():
    import subprocess
    import sys

    code = ("import sys\n"
            "from contactflow.embodiments.world import World, WorldParams\n"
            "from contactflow.embodiments.sim_robot import SimRobot\n"
            "from contactflow.embodiments.hand_geometry import hand_points\n"
            "for r in ('tombatossals', 'baxter'):\n"  # spheres at the Allegro's tips, cylinders on Baxter's grippers
            "    sim = SimRobot(World(WorldParams()), r)\n"
            "    assert all(len(hand_points(sim, a.name)) > 100 for a in sim.spec.arms if a.hand)\n"
            "print('open3d' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "False", out.stderr[-2000:]


def test_the_render_probe_runs_once_and_the_processes_it_starts_inherit_its_answer(monkeypatch):
    from contactflow.embodiments.sensors import render_camera

    probes: list[list[str]] = []

    def probe(argv, **kw):
        probes.append(argv)
        return subprocess.CompletedProcess(argv, 0, stdout="render-ok\n", stderr="")

    monkeypatch.setattr(render_camera.subprocess, "run", probe)
    monkeypatch.delenv(render_camera.RENDER_ENV, raising=False)
    render_camera.render_available.cache_clear()
    try:
        assert render_camera.render_available() and len(probes) == 1
        assert os.environ[render_camera.RENDER_ENV] == "1"  # what a node process started now sees
        render_camera.render_available.cache_clear()  # as a fresh process with that environment
        assert render_camera.render_available() and len(probes) == 1
        monkeypatch.setenv(render_camera.RENDER_ENV, "0")  # set by hand: the ray-cast camera, no probe
        render_camera.render_available.cache_clear()
        assert not render_camera.render_available() and len(probes) == 1
    finally:
        render_camera.render_available.cache_clear()
