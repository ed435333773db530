"""Wire messages of the interface layer: joint states and commands, wrenches, tactile arrays, depth, ground truth."""

from __future__ import annotations

from enum import StrEnum

import msgspec
import numpy as np

from contactflow.nodes.messages import ParamValue
from contactflow.nodes.wire import Message, NDArray


class JointState(Message, tag="joint_state"):
    """All joints of one robot in one message (thesis §6.3.1), published at 200 Hz."""

    robot: str  # robot name (one key segment)
    names: list[str]  # joint names, in the order of the arrays
    position: NDArray  # (n,) float64, rad or m
    velocity: NDArray  # (n,) float64
    effort: NDArray  # (n,) float64, N m or N


class JointCommand(Message, tag="joint_command"):
    """A position (and velocity) command for some joints from one source, mixed by ``weight``."""

    names: list[str]  # the joints commanded
    position: NDArray  # (k,) float64
    velocity: NDArray | None = None  # (k,) float64
    weight: float = 1.0  # mixing weight of this source, (0, 1]
    source: str = ""  # the commanding module


class CartesianTarget(Message, tag="cartesian_target"):
    """A Cartesian controller input: pose (16 values, row-major 4x4), twist or wrench (6 values) in ``frame``."""

    arm: str  # the arm's name
    mode: str  # pose | twist | wrench | stop
    frame: str = "world"  # the frame the values are expressed in
    values: list[float] = []  # 16 (pose) or 6 (twist, wrench) values; empty for stop
    speed: float = 0.1  # m/s for pose moves


class Wrench(Message, tag="wrench"):
    """Wrist F/T reading: force (N) and torque (N m) in world axes at the sensor origin."""

    arm: str  # the arm's name
    sensor_frame: str  # the F/T sensor's link
    force: list[float]  # N, world axes
    torque: list[float]  # N m, world axes, about the sensor origin
    estimated: bool = False  # solved from joint efforts, not measured


class TactileArray(Message, tag="tactile_array"):
    """Pressure images of every pad of one hand: ``pressure`` is (pads, rows, cols), N per taxel."""

    max_bytes = 1 << 20
    hand: str  # the hand's name
    pads: list[str]  # pad names, in the order of ``pressure``
    pressure: NDArray  # (pads, rows, cols) float32, N per taxel


class DepthImage(Message, tag="depth_image"):
    """Depth along the optical axis (m, 0 = no return), intrinsics and camera pose."""

    max_bytes = 8 << 20
    nonfinite = frozenset({"depth"})  # REP 117 depth: NaN no return, -inf too near, +inf too far (or 0: no return)
    camera: str  # the camera's name
    depth: NDArray  # (H, W) float32
    K: list[float]  # 3x3 row-major
    T_world_cam: list[float]  # 4x4 row-major, optical frame

    @classmethod
    def of(cls, depth: np.ndarray, K: np.ndarray, world_T_cam: np.ndarray, camera: str = "camera") -> DepthImage:
        """The message of a frame's depth (m), intrinsics and optical-frame pose."""
        return cls(camera=camera, depth=NDArray.of(np.ascontiguousarray(depth, dtype=np.float32)),
                   K=[float(v) for v in np.ravel(K)], T_world_cam=[float(v) for v in np.ravel(world_T_cam)])


class PointCloud(Message, tag="point_cloud"):
    """World-frame points (N, 3) float32; ``origin`` is the sensor's viewpoint [x, y, z] (empty when unknown)."""

    max_bytes = 16 << 20
    points: NDArray  # (N, 3) float32, m
    frame: str = "world"  # the frame of ``points``
    origin: list[float] = []  # m, the sensor's viewpoint; empty when unknown
    sensor: str = ""  # the sensor that saw them


class RobotModel(Message, tag="robot_model"):
    """The spherical robot model (App. B) posed from one joint state, world frame.

    Bi-spheres (``c1``, ``r1``, ``c2``, ``r2``; a sphere has ``c1 == c2``), one per link or a few for
    a flat one (``links`` names each one's link), and the world poses of named frames (sensor
    links) at the same joint state; ``t`` is the time of that joint state.
    """

    max_bytes = 4 << 20
    robot: str
    t: float  # s, time of the joint state the model was posed from
    links: list[str]  # a link name per bi-sphere
    c1: NDArray  # (m, 3) float64, m
    r1: NDArray  # (m,) float64, m
    c2: NDArray  # (m, 3) float64, m
    r2: NDArray  # (m,) float64, m
    regions: list[str] = []  # per link, the hand part it is: "finger", "palm" or "" (none given: no hand parts known)
    frames: list[str] = []  # named frames (sensor links) posed in ``poses``
    poses: NDArray | None = None  # (k, 4, 4) float64, world pose of each of ``frames``


class TaxelPoses(Message, tag="taxel_poses"):
    """World position and outward normal of every taxel of one hand, laid out like ``TactileArray.pressure``."""

    max_bytes = 4 << 20
    robot: str
    hand: str  # the hand's name
    t: float  # s, time of the joint state the taxels were posed from
    pads: list[str]  # pad names, in the order of the arrays
    positions: NDArray  # (pads, rows, cols, 3) float64, m, world
    normals: NDArray  # (pads, rows, cols, 3) float64, unit, world


class ObjectPoses(Message, tag="object_poses"):
    """Ground truth (evaluation key only): object poses (N, 4, 4)."""

    names: list[str]  # object names
    poses: NDArray  # (N, 4, 4) float64, world pose of each object


class TrueContacts(Message, tag="true_contacts"):
    """Ground truth (evaluation key only): physics contact points between named bodies."""

    max_bytes = 4 << 20
    body_a: list[str]  # per contact point: the robot's link
    body_b: list[str]  # per contact point: the object
    positions: NDArray  # (N, 3)
    normals: NDArray  # (N, 3)
    forces: NDArray  # (N,), N


# -- a world's robot on the key space (cf/<site>/robot/<robot>/...) ----------------------------


class ArmState(msgspec.Struct, kw_only=True):
    """One arm's drives this tick."""

    name: str  # the arm's name
    q_cmd: NDArray  # (n,) float64, rad: the joints' commanded position
    applied: int = 0  # the sender's sequence number of the last arm command the world applied


class HandState(msgspec.Struct, kw_only=True):
    """One hand: encoder readings and its controller's status."""

    name: str  # the hand's name
    positions: NDArray  # (n,) float64, rad or m: finger encoders
    status: str  # idle | running | success | failure of its controller
    effort: float = 1.0  # 0..1, the finger drives' force limit in force (a gripper's motor effort)
    applied: int = 0  # the sender's sequence number of the last hand command the world applied


class WrenchSample(msgspec.Struct, kw_only=True):
    """One wrist F/T sample: world axes at the sensor origin; ``force``/``torque`` minus the last tare."""

    arm: str  # the arm's name
    force: list[float]  # N
    torque: list[float]  # N m
    frame: str  # sensor link
    rotation: list[float]  # 9 values, row-major: the sensor frame's axes in the world
    estimated: bool = False  # solved from joint efforts, not measured
    external_force: list[float]  # N: untared, minus the hand's own weight and motion (what the environment and a held load exert)
    external_torque: list[float]  # N m, likewise


class TactileSample(msgspec.Struct, kw_only=True):
    """The pressure images of one hand's pads."""

    hand: str  # the hand's name
    pads: list[str]  # pad names, in the order of ``pressure``
    pressure: NDArray  # (pads, rows, cols) float32, N per taxel


class RobotState(Message, tag="robot_state"):
    """Everything a controller reads of one robot after world tick ``tick`` (published every tick)."""

    max_bytes = 4 << 20
    robot: str
    tick: int  # the world tick after which it was taken
    t: float  # s, simulated time after the tick
    names: list[str]  # every active joint
    position: NDArray  # (n,) float64, rad or m
    velocity: NDArray  # (n,) float64
    arms: list[ArmState]  # every arm's controller
    hands: list[HandState]  # every hand
    wrenches: list[WrenchSample] = []  # every wrist F/T sensor
    tactile: list[TactileSample] = []  # every hand's tactile pads
    failed: bool = False  # stopped by a hardware fault (the robot does not move again)
    failure: str = ""  # what the fault was
    held: bool = False  # held by the world: its controller died or stalled (until a command comes)
    held_at: int = -1  # the tick the hold began (-1: not held); a controller that connected later may take over
    refused: int = 0  # commands refused so far (unknown part, non-finite, outside the joint limits)
    late: int = 0  # commands applied a tick or more after the state they answered (real-time clock)


class ArmCommandKind(StrEnum):
    """What an arm command asks of the arm's drives (its controllers run on the commanding node)."""

    TARGET = "target"  # values: (2, n) joint position (rad) and velocity (rad/s) targets, held until the next
    TARE = "tare"  # zero the arm's wrist F/T sensor


class ArmCommand(Message, tag="arm_command"):
    """A command to one arm's drives; ``seq`` comes back in :class:`ArmState` once applied.

    A node's arm controllers (joint paths, Cartesian, admittance, guarded moves: thesis §6.3.2)
    send the arm's joint target every control tick while they run; the world holds the last one.
    """

    max_bytes = 1 << 20
    robot: str
    arm: str  # the arm's name
    kind: ArmCommandKind  # what ``values`` hold
    seq: int  # the sender's sequence number, echoed as ``applied`` once applied
    values: NDArray | None = None  # float64, (2, n) for a target


class HandCommand(Message, tag="hand_command"):
    """Finger targets (``values``) or a named preshape of one hand, at ``effort`` of the force limit."""

    robot: str
    hand: str  # the hand's name
    seq: int  # the sender's sequence number, echoed as ``applied`` once applied
    values: NDArray | None = None  # (n,) float64 finger joint targets, rad or m
    preshape: str = ""  # a named preshape of the hand (open, closed, ...), instead of values
    effort: float = 1.0  # fraction of the fingers' force limit, (0, 1]


class HeadCommand(Message, tag="head_command"):
    """Joint targets of the pan-tilt head (clipped to its limits)."""

    robot: str
    values: list[float]  # rad


class CameraRequest(Message, tag="camera_request"):
    """Ask the world for a frame of a robot's camera at the current tick."""

    robot: str
    camera: str  # the camera's name
    request: int  # the requester's number, echoed in the frame


class CameraFrame(Message, tag="camera_frame"):
    """One depth frame, answering :class:`CameraRequest` ``request``; or, with ``error``, why there is none."""

    max_bytes = 32 << 20
    nonfinite = frozenset({"depth"})  # as a depth image's
    robot: str
    camera: str  # the camera's name
    request: int  # the request it answers
    t: float  # s, when the frame was taken; -1: the camera never delivered one (a lost stream)
    depth: NDArray  # (H, W) float32, m along the optical axis, 0 = no return
    points: NDArray  # (N, 3) float64, world, valid pixels only
    pixels: NDArray  # (N, 2) int32, (row, col) of each point
    K: list[float]  # 9 values, row-major intrinsics
    pose: list[float]  # 16 values, row-major world pose of the optical frame
    error: str = ""  # why the camera gave no frame (the arrays are then empty); "": a frame


class ObstacleMsg(msgspec.Struct, kw_only=True):
    """A fixture of the cell (known layout, not a simulation readout), as the planners use it."""

    name: str  # the fixture's name
    kind: str  # box | cylinder | sphere | capsule
    size: list[float]  # m
    pose: list[float]  # 16 values, row-major world pose


class HandPoints(msgspec.Struct, kw_only=True):
    """The space a hand takes around its arm's controlled frame, measured on its collision geometry."""

    arm: str  # the arm's name
    points: NDArray  # (N, 3) float64, m, in the arm's controlled frame, hand as it started


class InfoRequest(Message, tag="info_request"):
    """Ask a world what one of its robots is (query on ``robot/<robot>/info``; the answer is `robot_info`)."""


class RobotInfo(Message, tag="robot_info"):
    """What a world's robot is (answered on ``robot/<robot>/info``): its embodiment, base, hands and cell fixtures."""

    max_bytes = 8 << 20
    robot: str
    embodiment: str  # registry name
    base: list[float]  # 16 values, row-major world pose of the base
    fixtures: list[ObstacleMsg] = []  # the cell's fixtures (table, box walls)
    hands: list[HandPoints] = []  # each arm's hand volume
    world: str = ""  # the world module's address
    clock: str = "lockstep"  # lockstep | realtime
    control_rate: float = 200.0  # Hz, one tick
    seed: int = 0  # the run's seed: controllers seed their planners with it, so a run repeats


# -- a robot's predictor (cf/<site>/predict/<robot>/...) -----------------------------------------


class PredictedState(Message, tag="predicted_state"):
    """What a robot's predictor (its own simulation, fed the robot's commands) holds after world tick ``tick``."""

    max_bytes = 4 << 20
    robot: str
    tick: int  # the world tick it predicts the state after
    t: float  # s, simulated time of that tick
    names: list[str]  # every active joint
    position: NDArray  # (n,) float64, rad or m: predicted joints
    joint_error: float  # rad, largest difference of an arm joint from the measured
    objects: list[str] = []  # the objects the predictor believes in
    poses: NDArray | None = None  # (k, 4, 4) float64, their predicted world poses
    contacts: NDArray | None = None  # (m, 3) float64, m: predicted contact points of the robot's hands, world
    contact_links: list[str] = []  # the link of each contact point
    contact_hands: list[str] = []  # the hand of each contact point
    arms: list[str] = []  # the arms with a wrist F/T
    force: list[float] = []  # N, per arm 3 values: predicted external force at the wrist, world axes
    force_error: list[float] = []  # N, per arm: its difference from the measured external force
    compute: float = 0.0  # s of wall time the predictor spent on its simulation and comparisons so far


class MismatchKind(StrEnum):
    """How prediction and sensing disagree (thesis §5.7)."""

    UNEXPECTED_CONTACT = "unexpected_contact"  # a sensed contact where none was predicted
    MISSING_CONTACT = "missing_contact"  # a predicted contact that was not sensed (never came, or lost)
    JOINTS = "joints"  # the measured arm joints left the predicted ones (an arm held back, pushed)
    FORCE = "force"  # the measured wrist load differs from the predicted (a heavier object, a push)
    OBJECT = "object"  # perception saw an object away from where the prediction holds it


class PredictionMismatch(Message, tag="prediction_mismatch"):
    """Prediction and sensing disagree: what differed, where and since when."""

    robot: str
    kind: MismatchKind  # what differed
    t: float  # s, simulated time at which it was decided
    since: float  # s, simulated time at which the difference began (the evidence's time)
    location: list[float] = []  # m, world: where (contacts), empty when it has no place
    part: str = ""  # the hand or arm concerned, when known
    value: float = 0.0  # the size of the difference: m for contacts (distance to the nearest counterpart, -1: none), rad, N
    bound: float = 0.0  # the bound it crossed, same unit
    detail: str = ""  # human-readable what
    update: str = ""  # the model update it taught the predictor (a held object's mass), "": none


class LookAheadRequest(Message, tag="look_ahead_request"):
    """Ask a robot's predictor what a primitive would do from the predicted state now (on ``predict/<robot>/ask``)."""

    robot: str
    request: int  # the asker's number, echoed in the answer
    primitive: str  # a primitive type (``transport``, ``place``, ...)
    params: dict[str, ParamValue] = {}  # its parameters, as a RUN control message gives them
    horizon: float = 20.0  # s of simulated time the primitive may run before the answer is timeout


class LookAheadEvent(msgspec.Struct, kw_only=True):
    """An event the primitive raised in the look-ahead."""

    t: float  # s of simulated time from the start of the look-ahead
    event: str  # the event
    detail: str = ""  # the event's detail


class LookAheadReply(Message, tag="look_ahead_reply"):
    """What the primitive did in the predictor's look-ahead (on ``predict/<robot>/ahead``), answering ``request``."""

    max_bytes = 4 << 20
    robot: str
    request: int  # the request it answers
    primitive: str  # the primitive type asked about
    outcome: str  # success | failure | error | timeout of the primitive; "" when the look-ahead could not run
    duration: float  # s of simulated time the primitive ran
    wall: float  # s of wall time the look-ahead took (build and run)
    events: list[LookAheadEvent] = []  # every event the primitive raised, in order
    objects: list[str] = []  # the believed movable objects
    moved: list[float] = []  # m, how far each object's centre moved
    tilted: list[float] = []  # rad, how far each object's up axis turned from where it was (> 0.5: it fell over)
    touched: list[str] = []  # the objects the robot touched during the look-ahead
    error: str = ""  # why the look-ahead could not run (unknown primitive, bad parameter, busy)
