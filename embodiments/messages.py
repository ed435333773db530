"""Wire messages of the interface layer: joint states and commands, wrenches, tactile arrays, depth, ground truth."""

from __future__ import annotations

from contactflow.nodes.wire import Message, NDArray


class JointState(Message, tag="joint_state"):
    """All joints of one robot in one message (thesis §6.3.1), published at 200 Hz."""

    robot: str
    names: list[str]
    position: NDArray  # (n,) float64, rad or m
    velocity: NDArray  # (n,) float64
    effort: NDArray  # (n,) float64, N m or N


class JointCommand(Message, tag="joint_command"):
    """A position (and velocity) command for some joints from one source, mixed by ``weight``."""

    names: list[str]
    position: NDArray  # (k,) float64
    velocity: NDArray | None = None  # (k,) float64
    weight: float = 1.0
    source: str = ""


class CartesianTarget(Message, tag="cartesian_target"):
    """A Cartesian controller input: pose (16 values, row-major 4x4), twist or wrench (6 values) in ``frame``."""

    arm: str
    mode: str  # pose | twist | wrench | stop
    frame: str = "world"
    values: list[float] = []
    speed: float = 0.1  # m/s for pose moves


class Wrench(Message, tag="wrench"):
    """Wrist F/T reading: force (N) and torque (N m) in world axes at the sensor origin."""

    arm: str
    sensor_frame: str
    force: list[float]
    torque: list[float]
    estimated: bool = False


class TactileArray(Message, tag="tactile_array"):
    """Pressure images of every pad of one hand: ``pressure`` is (pads, rows, cols), N per taxel."""

    max_bytes = 1 << 20
    hand: str
    pads: list[str]
    pressure: NDArray


class DepthImage(Message, tag="depth_image"):
    """Depth along the optical axis (m, 0 = no return), intrinsics and camera pose."""

    max_bytes = 8 << 20
    camera: str
    depth: NDArray  # (H, W) float32
    K: list[float]  # 3x3 row-major
    T_world_cam: list[float]  # 4x4 row-major, optical frame


class PointCloud(Message, tag="point_cloud"):
    """World-frame points (N, 3) float32; ``origin`` is the sensor's viewpoint [x, y, z] (empty when unknown)."""

    max_bytes = 16 << 20
    points: NDArray
    frame: str = "world"
    origin: list[float] = []
    sensor: str = ""


class RobotModel(Message, tag="robot_model"):
    """The spherical robot model (App. B) posed from one joint state, world frame.

    One bi-sphere per link (``c1``, ``r1``, ``c2``, ``r2``; a sphere has ``c1 == c2``) and the
    world poses of named frames (sensor links) at the same joint state; ``t`` is the time of
    that joint state.
    """

    max_bytes = 4 << 20
    robot: str
    t: float
    links: list[str]
    c1: NDArray  # (m, 3) float64, m
    r1: NDArray  # (m,) float64, m
    c2: NDArray  # (m, 3) float64, m
    r2: NDArray  # (m,) float64, m
    frames: list[str] = []
    poses: NDArray | None = None  # (k, 4, 4) float64, world pose of each of ``frames``


class TaxelPoses(Message, tag="taxel_poses"):
    """World position and outward normal of every taxel of one hand, laid out like ``TactileArray.pressure``."""

    max_bytes = 4 << 20
    robot: str
    hand: str
    t: float  # s, time of the joint state the taxels were posed from
    pads: list[str]
    positions: NDArray  # (pads, rows, cols, 3) float64, m, world
    normals: NDArray  # (pads, rows, cols, 3) float64, unit, world


class ObjectPoses(Message, tag="object_poses"):
    """Ground truth (evaluation key only): object poses (N, 4, 4)."""

    names: list[str]
    poses: NDArray


class TrueContacts(Message, tag="true_contacts"):
    """Ground truth (evaluation key only): physics contact points between named bodies."""

    max_bytes = 4 << 20
    body_a: list[str]
    body_b: list[str]
    positions: NDArray  # (N, 3)
    normals: NDArray  # (N, 3)
    forces: NDArray  # (N,), N
