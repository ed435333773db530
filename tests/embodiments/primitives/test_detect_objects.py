"""detect_objects selects among the vision chain's clusters when its objects port is wired, else segments a camera frame (no simulator)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from contactflow.embodiments import registry
from contactflow.embodiments.control.kinematics import Kinematics
from contactflow.embodiments.control.planning import Obstacle
from contactflow.embodiments.facade import RobotFacade
from contactflow.embodiments.primitives.detect_objects import DetectObjects
from contactflow.embodiments.transforms import xyz_rpy_to_matrix
from contactflow.nodes.status import Event, Status
from contactflow.nodes.testing import FakeIO
from contactflow.nodes.wire import MsgId
from contactflow.recognition.messages import PlaneMsg, SegmentedObjects
from contactflow.recognition.pipeline import Plane, extract_clusters

TABLE = 0.75  # m, top of tombatossals' table
TABLE_BOX = Obstacle("table/0", "box", (0.8, 1.4, TABLE), xyz_rpy_to_matrix((0.65, 0.0, TABLE / 2), (0.0, 0.0, 0.0)))
"""The table of World.add_table, as the world declares it to the planners."""
REGION = (0.3, -0.6, 0.74, 1.0, 0.1, 1.2)  # m, the pick-and-place region of the thesis tasks
CAN = (0.55, -0.3)  # m, where the can stands (the pick_place cell's)
FRAME = MsgId(source="lab/vision3d/kinect/depth", seq=7)


class StillRobot(RobotFacade):
    """tombatossals at its home joints, without a simulator; its camera frame is whatever the test sets."""

    failed = False
    head = None

    def __init__(self) -> None:
        spec = registry.get("tombatossals")
        self.name, self.spec = spec.name, spec
        self.kin = Kinematics(spec.urdf(), xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy))
        q = self.kin.q.copy()
        for a in spec.arms:
            q[self.kin.q_index(a.joints)] = a.home
        self.kin.update(q)
        self._arms = {a.name: a for a in spec.arms}
        self._hands = {h.name: h for h in spec.hands}
        self.time = 2.0
        self.frame = None
        self.frames = 0  # camera frames taken
        self.cell: list[Obstacle] = []  # the fixtures the reachability clears (none: no cell declared)

    def _sync_kin(self) -> None:
        return None

    def kin_q_cmd(self) -> np.ndarray:
        return self.kin.q.copy()  # still: commanded where it stands

    def camera(self, name: str = "kinect"):
        self.frames += 1
        return self.frame

    def fixtures(self) -> list:
        return list(self.cell)


def can(xy: tuple[float, float], radius: float = 0.03, height: float = 0.12, base: float = TABLE) -> np.ndarray:
    """Points on the top and the side of an upright cylinder standing at height ``base``."""
    rng = np.random.default_rng(int(1000 * (xy[0] + 2 * xy[1])) % 2**32)
    r, a = radius * np.sqrt(rng.uniform(0, 1, 300)), rng.uniform(0, 2 * np.pi, 300)
    top = np.column_stack([xy[0] + r * np.cos(a), xy[1] + r * np.sin(a), np.full(300, base + height)])
    a, z = rng.uniform(0, 2 * np.pi, 600), rng.uniform(base + 0.012, base + height, 600)
    side = np.column_stack([xy[0] + radius * np.cos(a), xy[1] + radius * np.sin(a), z])
    return np.vstack([top, side])


def table_plane() -> Plane:
    return Plane(np.array([0.0, 0.0, 1.0]), -TABLE, np.array([0.6, 0.0, TABLE]), np.eye(3), 5000)


def objects(*clouds: np.ndarray, depth_t: float) -> SegmentedObjects:
    """The vision chain's message: one cluster per cloud (as its cluster extractor made them, upright on the table)."""
    plane = table_plane()
    clusters = [extract_clusters(c, eps=0.1, min_size=10, plane=plane)[0] for c in clouds]
    return SegmentedObjects.of(clusters, FRAME, depth_t)


def started(wired: bool, cell: tuple[Obstacle, ...] = (), **params) -> tuple[DetectObjects, FakeIO, StillRobot]:
    robot = StillRobot()
    robot.cell = list(cell)
    params = {"arm": "right", "region": REGION, "standoff": 0.04, **params}
    prim = DetectObjects("detect_objects", DetectObjects.Params(**params))
    io = FakeIO(wired_ports={"objects", "plane"} if wired else set())
    io.module = prim
    prim.setup(io)
    prim.bind(robot)
    prim.start()
    return prim, io, robot


def run(prim: DetectObjects, robot: StillRobot, seconds: float, dt: float = 0.02) -> Status:
    status = Status.RUNNING
    for _ in range(int(round(seconds / dt))):
        robot.time += dt
        status = prim.step()
        if status.finished:
            break
    return status


def test_a_wired_detect_objects_selects_in_the_region_among_the_vision_chains_fresh_clusters():
    prim, io, robot = started(wired=True)
    io.feed("plane", PlaneMsg.of(table_plane()))
    # a larger object beyond the region's y, and a message of a frame taken before the settle: neither is chosen
    io.feed("objects", objects(can(CAN), depth_t=robot.time - 0.5))
    assert run(prim, robot, 0.5) is Status.RUNNING
    io.feed("objects", objects(can((0.55, 0.3), radius=0.05), can(CAN), depth_t=robot.time))
    assert run(prim, robot, 0.1) is Status.SUCCESS
    assert robot.frames == 0  # no camera frame of its own
    detected, outcome = io.events
    assert detected.event is Event.OBJECT_DETECTED and outcome.event is Event.SUCCESS
    assert "vision chain, depth frame lab/vision3d/kinect/depth#7" in outcome.detail
    v = outcome.values
    assert (v["count"], v["cx"], v["cy"]) == pytest.approx((1, *CAN), abs=0.01)
    assert v["top"] == pytest.approx(TABLE + 0.12, abs=0.005) and v["dz"] == pytest.approx(-1.0, abs=1e-6)


def test_a_cluster_cut_to_the_region_is_clustered_again():
    """The chain joined two cans through the bottom of the box they stand in; off the known support they are two."""
    bottom = TABLE + 0.05
    prim, io, robot = started(wired=True, support_z=bottom, select="leftmost")
    gx, gy = np.meshgrid(np.arange(0.45, 0.65, 0.01), np.arange(-0.4, -0.05, 0.01))
    floor = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, bottom)])
    io.feed("objects", objects(np.vstack([floor, can(CAN, base=bottom), can((0.55, -0.15), 0.04, base=bottom)]),
                               depth_t=robot.time + 0.2))
    assert run(prim, robot, 0.3) is Status.SUCCESS
    v = io.events[-1].values
    assert v["count"] == 2 and (v["cx"], v["cy"], v["size_y"]) == pytest.approx((0.55, -0.15, 0.08), abs=0.01)


def test_leftmost_selects_among_the_clusters_by_their_y():
    prim, io, robot = started(wired=True, select="leftmost")
    io.feed("objects", objects(can((0.5, -0.4), radius=0.04), can((0.6, -0.15)), depth_t=robot.time + 0.2))
    assert run(prim, robot, 0.3) is Status.SUCCESS
    assert (io.events[-1].values["cx"], io.events[-1].values["cy"]) == pytest.approx((0.6, -0.15), abs=0.01)


def test_a_wired_region_without_objects_is_object_not_found_and_silence_is_a_failure():
    prim, io, robot = started(wired=True)
    io.feed("objects", objects(can((0.55, 0.3)), depth_t=robot.time + 0.2))
    assert run(prim, robot, 0.3) is Status.FAILURE
    assert io.events[-1].event is Event.OBJECT_NOT_FOUND and "vision chain" in io.events[-1].detail

    prim, io, robot = started(wired=True, timeout=1.0)
    assert run(prim, robot, 1.0) is Status.RUNNING
    assert run(prim, robot, 0.2) is Status.FAILURE
    assert io.events[-1].event is Event.FAILURE and "vision chain sent no objects" in io.events[-1].detail
    assert robot.frames == 0


def test_unwired_it_segments_a_camera_frame():
    prim, io, robot = started(wired=False)
    gx, gy = np.meshgrid(np.arange(0.31, 0.99, 0.01), np.arange(-0.59, 0.09, 0.01))
    table = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, TABLE)])
    robot.frame = SimpleNamespace(t=robot.time, points=np.vstack([table, can(CAN)]))
    io.feed("objects", objects(can((0.6, -0.15)), depth_t=robot.time + 0.2))  # an unwired port is not read
    assert run(prim, robot, 0.2) is Status.SUCCESS
    assert robot.frames == 1 and "camera kinect" in io.events[-1].detail
    assert (io.events[-1].values["cx"], io.events[-1].values["cy"]) == pytest.approx(CAN, abs=0.01)


BOTTLE = (0.55, 0.0)  # m, a bottle of bench unscrew (bottle 4: 12 cm body, 3 cm radius) on the table before the left hand
SIDE = {"arm": "left", "region": (0.3, -0.3, 0.74, 0.8, 0.3, 1.2), "direction": (0.0, -1.0, 0.0), "preshape": "open"}


def bottle(xy: tuple[float, float]) -> np.ndarray:
    """Points of a screw bottle standing on the table as the robot's head camera sees it (the tops and a third of
    the sides toward -x): a 12 cm body of 3 cm radius, its shoulder, a 4 cm neck and a 2 cm cap (bottle 4 of
    bench unscrew)."""
    rng = np.random.default_rng(4)

    def ring(n: int, r0: float, r1: float, z0: float, z1: float) -> np.ndarray:
        side = z0 != z1  # a side: the third the camera sees
        a = rng.uniform(2 * np.pi / 3, 4 * np.pi / 3, n) if side else rng.uniform(0, 2 * np.pi, n)
        r, z = np.sqrt(rng.uniform(r0**2, r1**2, n)), rng.uniform(z0, z1, n)
        return np.column_stack([xy[0] + r * np.cos(a), xy[1] + r * np.sin(a), z])

    body, neck, cap = TABLE + 0.12, TABLE + 0.16, TABLE + 0.18
    return np.vstack([ring(600, 0.03, 0.03, TABLE + 0.012, body), ring(200, 0.012, 0.03, body, body),
                      ring(100, 0.012, 0.012, body, neck), ring(60, 0.015, 0.015, neck, cap), ring(100, 0.0, 0.015, cap, cap)])


def side_grasp(cell: tuple[Obstacle, ...], **params) -> tuple[Status, dict]:
    prim, io, robot = started(wired=True, cell=cell, **SIDE, **params)
    io.feed("objects", objects(bottle(BOTTLE), depth_t=robot.time + 0.2))
    status = run(prim, robot, 0.3)
    return status, dict(io.events[-1].values) | {"detail": io.events[-1].detail}


def test_a_side_grasp_beside_a_short_object_is_raised_until_the_arm_reaches_it_clear_of_the_table():
    """At the object's middle the left wrist (panda link 7) and the ring finger of a side grasp are in the table:
    the approach goes up the object until a posture clear of it exists, and no higher than the grasp height."""
    from contactflow.recognition.reachability import ArmReach

    free, v_free = side_grasp(cell=())
    assert free is Status.SUCCESS
    status, v = side_grasp(cell=(TABLE_BOX,))
    assert status is Status.SUCCESS
    centre = v_free["z"] - v_free["cz"]  # the grasp frame's height over the grasp centre (tombatossals' open hand)
    assert centre == pytest.approx(-0.015, abs=1e-3)  # without a table: the grasp centre level with the centroid
    raised_by = v["z"] - v_free["z"]
    assert raised_by > 0.005 and v["z"] - centre <= v["grasp_z"] + 1e-6
    assert raised_by == pytest.approx(round(raised_by / 0.01) * 0.01, abs=1e-6)  # in steps of raise_step
    pose = xyz_rpy_to_matrix((v["x"], v["y"], v["z"]), (v["roll"], v["pitch"], v["yaw"]))
    clear = ArmReach("tombatossals", "left", StillRobot().kin.base, restarts=16, iters=300, obstacles=[TABLE_BOX])
    assert clear(pose) is not None
    low = pose.copy()
    low[2, 3] = v_free["z"]
    assert clear(low) is None  # the centroid's height: only postures in the table


def test_a_side_grasp_that_is_not_raised_finds_no_approach_clear_of_the_table():
    status, v = side_grasp(cell=(TABLE_BOX,), raise_step=0.0)
    assert status is Status.FAILURE and "no approach vector" in v["detail"]


def test_a_negative_raise_step_is_refused_naming_the_parameter():
    with pytest.raises(ValueError, match="raise_step"):
        started(wired=True, raise_step=-0.01)
