"""Benchmark: Table 4.1 in simulation — contact detection rate and localisation per modality.

A hand touches a fixed object (box, cylinder, spray-bottle-like) from 15 approach
directions each (5 azimuths x 3 elevations) with a guarded move that stops when the wrist
F/T feels the touch. At the stop every generator runs on the simulated sensors: tactile
pads (eq. 4.6), wrist F/T (eq. 4.8-4.9, hand model from the spherical model), a head-like
depth camera above and behind the robot (the arm hides the object at the touch; the grid
built before the approach carries the knowledge) + occupancy grid (§4.4.4; the object is fixed, so the range
generator runs with ``require_motion=False``) and simulator prediction support (§4.5.2: a
prediction scene with the object displaced by N(0, 2 cm), robot posed at the measured
joints; each predicted contact supports the voxels within those 2 cm). The rig (robot, arm,
hand, how the hand is held and moved) is a parameter, both by default side by side: ``tombatossals`` (the thesis's protocol: the Allegro hand touches with its
palm facing the direction, the thumb up; its arm stands on the table, so the touches come from
35-75 degrees above the horizontal and the moves to their starts are planned around the object
the Kinect sees) and ``melfa`` (arm + parallel gripper with two 5x8 pads, level to 50 degrees
down). After each touch the hand backs off the way it came. Per
modality the clouds are fused and condensed (threshold-cluster-centroid); a touch is
detected when a contact comes out, ε is the distance of the closest contact to the ground
truth (force-weighted mean of the simulator's true hand-object contact points, evaluation
only) and σ its spread. Touches where the hand never reached the object are left out, as
in the thesis. Writes ``contacts.json``, ``contacts.md`` and ``contacts_<robot>.png``.

That is the ``local`` executor. ``runtime`` runs the same touches through the runtime path,
in lockstep: a world node (the rig's robot, the table, the fixed object and the rig's camera, a
fixed camera of the scene file for melfa, streaming depth at CAMERA_HZ; the true contacts of its
robot with the object on ``eval/<robot>/true_contacts``), the robot's control node (the touches
as one task of ``move_to`` and ``touch`` primitive modules; ``contact_cues`` publishing its
tactile and wrist F/T clouds from the world's robot state; its predictor, believing the object
N(0, 2 cm) off, and the simulator support generator on what it predicts), a vision node (the
range generator on the world's depth stream) and a fusion node (``contact_fusion`` per modality,
of that modality's generators; the one of all on ``KeySpace.fused(robot, "contacts")``).
A touch counts when the world saw the hand on the object as the touch primitive felt the
wrist force (the local reading moment); a modality detects it when its service reports a
contact from then until the back-off, and ε is that contact's distance to the force-weighted
true contact point. The runtime's OGM is built from the first frame and follows every frame
after (the local one is built anew before each touch); its predictor draws one pose error per
object (the local scene one per touch). ``both`` prints the two side by side.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import tempfile
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import yaml
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from contactflow.fusion.condensation import CondensationParams, condense
from contactflow.fusion.generators.range import RangeGenerator, RangeParams, segment_object
from contactflow.fusion.generators.simulator import SimulatorParams, simulator_support
from contactflow.fusion.generators.tactile import tactile_hypotheses
from contactflow.fusion.hypotheses import Hypotheses
from contactflow.fusion.integrator import Integrator
from contactflow.fusion.sim_sources import hand_capsules, taxel_readings, wrist_hypotheses
from contactflow.nodes.stats import rate_text, wilson

MODALITIES = {
    "tactile": ("tactile",),
    "force": ("force",),
    "range": ("range",),
    "tactile + force": ("tactile", "force"),
    "all": ("tactile", "force", "range"),
    "all + simulator": ("tactile", "force", "range", "simulator"),
}
EXECUTORS = ("local", "runtime", "both")
THESIS = {"tactile": (20.9, 1.25, 0.20), "force": (79.1, 5.37, 1.18), "range": (58.1, 3.74, 0.73),
          "all": (90.7, 4.31, 1.10), "all + simulator": (90.7, 3.33, 1.11)}
TABLE_Z = 0.75
TARGET_Z = {"box": 0.82, "cylinder": 0.83, "bottle": 0.85}  # m, approach target heights


@dataclass(frozen=True)
class Rig:
    """Which robot touches, and how its hand is found in the models."""

    robot: str = "melfa"
    arm: str = "arm"
    hand: str = "gripper"
    ft_link: str = "panda_hand"
    hand_links: tuple[str, ...] = ("panda_hand", "panda_leftfinger", "panda_rightfinger")
    object_xy: tuple[float, float] = (0.56, 0.11)
    camera: str = ""  # the robot's own depth camera; "" = a fixed head-like camera above and behind
    facing: bool = False  # each touch turns the hand's approach axis (z) along its direction, its y axis up
    elevations: tuple[float, ...] = (0.0, 25.0, 50.0)  # deg below the horizontal, of the touch directions
    planned: bool = False  # the move to a touch's start is planned (OMPL) around the object as the camera sees it


RIGS = {
    # the thesis's protocol: the Allegro hand touches with its palm and fingers, the thumb up and clear of the
    # table; its arm stands on the table, so the hand comes from above (level, the elbow would meet the table)
    "tombatossals": Rig("tombatossals", "right", "right_hand", "right_palm_link",
                        ("right_palm_link", "right_link_"), (0.55, -0.30), camera="kinect", facing=True,
                        elevations=(35.0, 55.0, 75.0), planned=True),
    "melfa": Rig(),
}
START = 0.13  # m, a touch starts this far before the object's centre along its direction
POSE_SIGMA = 0.02  # m, object pose error of the prediction scene (thesis §4.7)
PRESS_FORCE = 1.5  # N, wrist force at which the touch is recorded
ROI = np.array([0.12, 0.12, 0.2])  # m, half size of the box around the object's centre the range generator reads


PLANNED_TIMEOUT = 15.0  # s, a planned move home or to a touch's start


def planned_move(rig: Rig, target: np.ndarray, around_object: bool) -> dict:
    """``move_to`` parameters of a planned rig's move to ``target`` (OMPL; around the object the camera sees)."""
    return {"arm": rig.arm, "target": _target(target), "speed": 0.25, "sense_obstacles": around_object}


def start_pose(rig: Rig, home: np.ndarray, centre: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The hand's pose where a touch along ``d`` starts: ``START`` before the object's centre, held as the rig holds it."""
    T = home.copy()
    if rig.facing:
        up = np.array([0.0, 0.0, 1.0]) - d[2] * d
        y = up / np.linalg.norm(up)
        T[:3, :3] = np.column_stack([np.cross(y, d), y, d])
    T[:3, 3] = centre - START * d
    return T


def object_specs(rig: Rig) -> dict:
    from contactflow.embodiments.world import ObjectSpec, ShapeSpec, bottle

    x, y = rig.object_xy
    b = bottle("obj", (x, y, TABLE_Z + 0.11))
    return {
        "box": ObjectSpec("obj", (ShapeSpec("box", (0.06, 0.06, 0.12)),), 0.2, 0.6, (x, y, TABLE_Z + 0.06),
                          static=True, category="box"),
        "cylinder": ObjectSpec("obj", (ShapeSpec("cylinder", (0.035, 0.14)),), 0.2, 0.6, (x, y, TABLE_Z + 0.07),
                               static=True, category="cylinder"),
        "bottle": dataclasses.replace(b, static=True),
    }


def directions(n_az: int = 5, elevations: tuple[float, ...] = (0.0, 25.0, 50.0)) -> list[np.ndarray]:
    """Approach directions (unit, world): azimuths across the front, tilting downwards."""
    out = []
    for el in np.radians(elevations):
        for az in np.radians(np.linspace(-60.0, 60.0, n_az)):
            out.append(np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)]))
    return out


@dataclass
class Touch:
    obj: str
    direction: list[float]
    truth: np.ndarray | None
    clouds: dict[str, Hypotheses] = field(default_factory=dict)
    wrench: tuple | None = None  # (f, tau, T_world_sensor, hand bi-spheres): to rerun the F/T generator


def _truth(world, robot_prefix: str, obj: str = "obj") -> np.ndarray | None:
    from contactflow.embodiments.sensors.ground_truth import read_ground_truth

    pts, w = [], []
    for c in read_ground_truth(world).contacts:
        names = {c.body_a, c.body_b}
        if obj in names and any(n.startswith(robot_prefix) for n in names):
            pts.append(c.position)
            w.append(c.force)
    if not pts:
        return None
    w = np.asarray(w)
    return (np.asarray(pts) * w[:, None]).sum(axis=0) / w.sum()


class PredictionScene:
    """A second world holding the robot model and the object at its believed pose."""

    def __init__(self, spec, rig: Rig) -> None:
        from contactflow.embodiments.world import World, WorldParams

        self.rig = rig
        self.world = World(WorldParams(timestep=0.0025))
        self.world.add_table()
        self.obj = self.world.add_object(spec)
        self.art = self.world.add_robot(rig.robot)
        self.home = self.obj.pose()

    def contacts(self, q: np.ndarray, offset: np.ndarray) -> np.ndarray:
        T = self.home.copy()
        T[:3, 3] += offset
        self.obj.set_pose(T)
        self.art.set_state(q)
        self.world.step(1)
        from contactflow.embodiments.sensors.ground_truth import body_name

        pts = []
        for c in self.world.contacts():
            names = {body_name(b) for b in c.bodies}
            if "obj" in names and any(n.startswith(f"{self.art.name}/{h}") for n in names for h in self.rig.hand_links):
                pts.extend(p.position for p in c.points)
        return np.asarray(pts, dtype=float).reshape(-1, 3)


def run_object(name: str, spec, rig: Rig, dirs: list[np.ndarray], rng: np.random.Generator, progress,
               task) -> list[Touch]:
    from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, run_primitive
    from contactflow.embodiments.registry import CameraSpec
    from contactflow.embodiments.sensors.camera import DepthCamera
    from contactflow.embodiments.sim_robot import SimRobot
    from contactflow.embodiments.world import World, WorldParams
    from contactflow.recognition.geometry import look_at

    world = World(WorldParams(timestep=0.0025))
    world.add_table()
    world.add_object(spec)
    robot = SimRobot(world, rig.robot)
    arm = robot.arm(rig.arm)
    runner = LocalPrimitiveRunner(robot) if rig.planned else None
    home_q = arm.q()
    home_T = arm.ee_pose()
    prediction = PredictionScene(spec, rig)
    centre = np.array([*rig.object_xy, TARGET_Z[name]])
    roi_lo, roi_hi = centre - ROI, centre + ROI
    rparams = RangeParams(table_z=TABLE_Z, require_motion=False)
    # A head-like depth camera above and behind the robot, looking at the object.
    if rig.camera:
        def read_depth():
            return robot.camera(rig.camera)
    else:
        camera = DepthCamera(world, CameraSpec(name="head", link=""),
                               T_world_cam=look_at(head_eye(rig), centre))

        def read_depth():
            return camera.read(robot.time)
    frame = read_depth()
    cam = frame.T_world_cam[:3, 3]
    obj_pts = segment_object(frame.points, robot.spherical.distance, rparams, roi_lo, roi_hi)
    touches = []
    back: np.ndarray | None = None
    for d in dirs:
        if back is not None:  # off the object first, the way it came (a hand on an edge would drag it home)
            arm.move_pose(back, speed=0.25)
            arm.wait(6.0)
        if runner is not None:
            run_primitive(runner, "move_to", planned_move(rig, home_T, False), max_time=PLANNED_TIMEOUT)
        else:
            arm.move_joints(home_q)
            arm.wait(6.0)
        rng_gen = RangeGenerator(rparams)
        rng_gen.initialize(obj_pts, cam)
        start = back = start_pose(rig, home_T, centre, d)
        if runner is not None:
            run_primitive(runner, "move_to", planned_move(rig, start, True), max_time=PLANNED_TIMEOUT)
        else:
            arm.move_pose(start, speed=0.25)
            arm.wait(6.0)
        touch = Touch(name, d.tolist(), None)
        robot.tare_ft(rig.arm)
        arm.guarded_move(np.concatenate([0.04 * d, np.zeros(3)]), max_force=2.5, duration=5.0)
        t_next = robot.time
        # Sensors are read at the first control step where the hand presses on the object
        # (true contact and a wrist force above the F/T generator's floor), before the
        # guarded move's stop lets the hand bounce off.
        while not arm.done() and not robot.failed:
            robot.step(0.005)
            if robot.time >= t_next:  # the OGM follows the approach at 4 Hz (swept space)
                t_next += 0.25
                rng_gen.observe(np.zeros((0, 3)), robot.spherical.distance, robot.time)
            touch.truth = _truth(world, f"{robot.name}/")
            if touch.truth is not None and np.linalg.norm(robot.ft(rig.arm).force) >= PRESS_FORCE:
                arm.stop()
                break
        else:
            touch.truth = None
        progress.advance(task)
        touches.append(touch)
        if touch.truth is None:
            continue
        now = robot.time
        pressure, taxels, normals = taxel_readings(robot, rig.hand)
        touch.clouds["tactile"] = tactile_hypotheses(pressure, taxels, now, normals)
        caps = hand_capsules(robot, rig.hand_links)
        touch.clouds["force"], touch.wrench = wrist_hypotheses(robot, rig.arm, rig.ft_link, caps, now)
        frame = read_depth()
        pts = segment_object(frame.points, robot.spherical.distance, rparams, roi_lo, roi_hi)
        touch.clouds["range"] = rng_gen.observe(pts, robot.spherical.distance, now)
        predicted = prediction.contacts(robot.art.qpos(), rng.normal(0.0, POSE_SIGMA, 3))
        # each predicted point spread over the object's pose uncertainty (§4.5.2): the scene's object is N(0, σ) off
        touch.clouds["simulator"] = simulator_support(predicted, now, SimulatorParams(dilate=POSE_SIGMA))
    return touches


TICK = 0.005  # s, the world's control tick (200 Hz)
HOLD = 0.2  # s the hand stays where the touch stopped
SETTLE = 0.05  # s after a touch felt the wrist force within which the world must see the hand on the object
GENERATORS = {"tactile": "tactile_{arm}", "force": "force_torque_{arm}", "range": "range", "simulator": "simulator"}
"""The runtime's generator (its module name, ``contacts/<robot>/<name>``) of each of the local bench's sources."""
CAMERA_HZ = 10.0  # Hz of simulated time, the world's depth frames on the runtime (the local OGM follows at 4 Hz)


def head_eye(rig: Rig) -> np.ndarray:
    """Where the fixed head-like camera of a rig without a camera of its own stands: above and behind the robot."""
    return np.array([-0.1, rig.object_xy[1], 1.45])


def fused_generators(rig: Rig) -> dict[str, tuple[str, ...]]:
    """The runtime's fusion services: modality -> the generators it fuses."""
    return {mod: tuple(GENERATORS[s].format(arm=rig.arm) for s in sources) for mod, sources in MODALITIES.items()}


def _target(T: np.ndarray) -> list[float]:
    from contactflow.embodiments.primitives.base import pose6

    v = pose6(T)
    return [v[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]


def touch_task(rig: Rig, home: np.ndarray, centre: np.ndarray, dirs: list[np.ndarray]) -> dict:
    """The touches of one object as one task, the local protocol step for step: for each direction the arm goes
    home, to the start 13 cm before the object, touches along the direction until the wrist feels
    PRESS_FORCE, holds still HOLD s and backs off to the start; each step follows the last whatever its outcome."""
    nodes: dict[str, dict] = {}
    order: list[str] = []
    for i, d in enumerate(dirs):
        start = start_pose(rig, home, centre, d)
        # as the local arm.move_pose + wait(6): no contact stops the move (a hand landing on the object on its way
        # to the start stays there, and the touch starts from where it is), 6 s at most
        move = {"arm": rig.arm, "planning": False, "speed": 0.25, "abort_force": 1e4}
        if rig.planned:  # the local bench's planned moves
            nodes[f"home_{i}"] = {"primitive": "move_to", "params": planned_move(rig, home, False),
                                  "timeout": PLANNED_TIMEOUT}
            nodes[f"approach_{i}"] = {"primitive": "move_to", "params": planned_move(rig, start, True),
                                      "timeout": PLANNED_TIMEOUT}
        else:
            nodes[f"home_{i}"] = {"primitive": "move_to", "params": {**move, "target": _target(home)}, "timeout": 6}
            nodes[f"approach_{i}"] = {"primitive": "move_to", "params": {**move, "target": _target(start)}, "timeout": 6}
        nodes[f"touch_{i}"] = {"primitive": "touch", "timeout": 10,
                               "params": {"arm": rig.arm, "direction": [float(v) for v in d], "frame": "world",
                                          "force_threshold": PRESS_FORCE, "velocity": 0.04, "max_distance": 0.2}}
        # the hand stays on the object a moment, as the local bench reads its sensors there: the back-off's
        # move_to tares the wrist sensor as it starts, and the F/T cues read after a tare in contact are void
        nodes[f"hold_{i}"] = {"primitive": "wait_event", "params": {"arm": rig.arm, "delay": HOLD}}
        nodes[f"back_{i}"] = {"primitive": "move_to", "params": {**move, "target": _target(start), "abort_force": 40.0},
                              "timeout": 6}
        order += [f"home_{i}", f"approach_{i}", f"touch_{i}", f"hold_{i}", f"back_{i}"]
    nodes["done"], nodes["failed"] = {"terminal": "success"}, {"terminal": "failure"}
    edges = []
    for a, b in zip(order, [*order[1:], "done"], strict=True):
        edges += [{"from": a, "to": b, "on": [["success", "failure", "timeout"]]}, {"from": a, "to": "failed", "on": "error"}]
    return {"main": "touches", "tasks": {"touches": {"params": {}, "timeout": 60 * len(dirs), "nodes": nodes, "edges": edges}}}


class _Streams:
    """The bench's session: each fusion service's contact lists and the world's true contacts, as they came."""

    def __init__(self, transport, fused: dict[str, str], truth: str, obj: str, clouds: str) -> None:
        self._lock = threading.Lock()
        self.obj = obj  # the touched object (the world reports the robot's contacts with the table too)
        self.fused: dict[str, list] = {m: [] for m in fused}  # modality -> [(stamp, [(location, sigma)])]
        self.truth: list[tuple[float, np.ndarray | None]] = []  # (sim s, force-weighted contact point)
        self.clouds: dict[str, list[int]] = {}  # generator -> [clouds, clouds with hypotheses]
        self._subs = [transport.subscribe(truth, self._on_truth), transport.subscribe(clouds, self._on_cloud)]
        for mod, key in fused.items():
            self._subs.append(transport.subscribe(key, lambda k, b, mod=mod: self._on_fused(mod, k, b)))

    def _on_fused(self, mod: str, key: str, payload: bytes) -> None:
        from contactflow.fusion.messages import ContactList
        from contactflow.nodes.wire import decode

        msg = decode(payload, ContactList, key)
        found = [(np.asarray(c.location), c.sigma) for c in msg.contacts]
        with self._lock:
            self.fused[mod].append((msg.stamp, found))

    def _on_cloud(self, key: str, payload: bytes) -> None:
        from contactflow.fusion.messages import HypothesisCloud
        from contactflow.nodes.wire import decode

        msg = decode(payload, HypothesisCloud, key)
        with self._lock:
            n = self.clouds.setdefault(msg.generator, [0, 0])
            n[0] += 1
            n[1] += len(msg.likelihood.numpy()) > 0

    def _on_truth(self, key: str, payload: bytes) -> None:
        from contactflow.embodiments.messages import TrueContacts
        from contactflow.nodes.wire import decode

        msg = decode(payload, TrueContacts, key)
        on = np.array([b == self.obj for b in msg.body_b], dtype=bool)
        w = msg.forces.numpy()[on]
        point = (msg.positions.numpy()[on] * w[:, None]).sum(axis=0) / w.sum() if w.sum() > 0 else None
        with self._lock:
            self.truth.append((msg.hdr.t_sim, point))

    def take(self) -> tuple[dict[str, list], list, dict[str, list[int]]]:
        with self._lock:
            return ({m: sorted(v, key=lambda x: x[0]) for m, v in self.fused.items()}, sorted(self.truth, key=lambda x: x[0]),
                    {g: list(n) for g, n in self.clouds.items()})

    def close(self) -> None:
        for sub in self._subs:
            sub.close()


def _windows(progress: list, events: list, n: int, tail: float = 0.3) -> list[tuple[float, float, float] | None]:
    """(contact, end) in simulated s of each touch that felt one: when its touch primitive felt the wrist force
    (the local bench's reading moment) and ``tail`` s into the back-off that follows."""
    entered = {m.node: m.hdr.t_sim for m in progress if m.kind == "entered"}
    out: list[tuple[float, float, float] | None] = []
    for i in range(n):
        if f"back_{i}" not in entered:
            out.append(None)
            continue
        t0, t1 = entered[f"touch_{i}"], entered[f"back_{i}"]
        felt = [e.hdr.t_sim for e in events if e.event == "contact" and e.module.rsplit("/", 1)[-1].startswith("touch")
                and t0 - 1e-9 <= e.hdr.t_sim <= t1 + 1e-9]
        out.append((min(felt), t1 + tail) if felt else None)
    return out


def judge_touch(window: tuple[float, float] | None, fused: dict[str, list], truth: list) -> dict:
    """One runtime touch, read as the local bench reads it: the hand on the object when the touch felt the
    wrist force (the world's first true contact from a tick before to SETTLE after it: a hand resting on an
    edge chatters), and per modality the first fused contacts from then until the back-off (the closest to
    the truth, its spread)."""
    if window is None:
        return {"truth": None, "modalities": {}}
    t_c, t1 = window
    touched = [(t, p) for t, p in truth if t_c - TICK - 1e-9 <= t <= t_c + SETTLE and p is not None]
    if not touched:
        return {"truth": None, "modalities": {}}
    point = touched[0][1]
    out = {}
    for mod, lists in fused.items():
        hit = next(((t, cs) for t, cs in lists if t_c - 1e-9 <= t <= t1 and cs), None)
        if hit is None:
            out[mod] = None
            continue
        t, contacts = hit
        loc, sigma = min(contacts, key=lambda c: float(np.linalg.norm(c[0] - point)))
        out[mod] = {"eps": float(np.linalg.norm(loc - point)), "sigma": float(sigma), "delay": t - t_c}
    return {"truth": point.tolist(), "t_touch": t_c, "modalities": out}


def run_object_runtime(name: str, spec, rig: Rig, dirs: list[np.ndarray], folder: pathlib.Path,
                       rng: np.random.Generator) -> tuple[list[dict], dict]:
    """The touches of one object on the runtime, in this process (a zenoh session per node, in lockstep): a world
    node (the rig's robot, the table, the fixed object, the rig's camera streaming depth; its true contacts on
    ``eval/``), the robot's control node (the touch task's primitive modules; ``contact_cues``, its tactile and
    wrist F/T generators; its posed model; its predictor, believing the object N(0, POSE_SIGMA) off, and the
    simulator support generator on its predictions), a vision node (the range generator on the depth stream) and
    a fusion node (one ``contact_fusion`` per modality, of the generators the local bench fuses for it; the one of
    every generator on ``KeySpace.fused(robot, ...)``). Returns the touches as judged, and what fed the fusion:
    the clouds of each generator (how many, how many with hypotheses) and each fusion's cycles per simulated s."""
    from contactflow.embodiments.layout import (
        control_node,
        start_nodes,
        stop_nodes,
        world_node,
        write_cell,
        zenoh,
    )
    from contactflow.embodiments.scene_file import CameraPlacement
    from contactflow.embodiments.sim_robot import SimRobot
    from contactflow.embodiments.world import World, WorldParams
    from contactflow.nodes.keys import KeySpace
    from contactflow.nodes.procs import free_port, wait_for

    world = World(WorldParams(timestep=0.0025))
    world.add_table()
    home = SimRobot(world, rig.robot).arm(rig.arm).ee_pose()
    centre = np.array([*rig.object_xy, TARGET_Z[name]])
    folder.mkdir(parents=True, exist_ok=True)
    task_file = folder / "touches.yaml"
    task_file.write_text(yaml.safe_dump(touch_task(rig, home, centre, dirs), sort_keys=False))
    cameras = [] if rig.camera else [CameraPlacement("head", tuple(head_eye(rig)), tuple(centre))]
    cell = write_cell(folder / "cell.yaml", rig.robot, [spec], cameras=cameras)
    off = rng.normal(0.0, POSE_SIGMA, 3)  # where the robot believes the object: its pose error (thesis §4.7)
    belief = write_cell(folder / "belief.yaml", rig.robot,
                        [dataclasses.replace(spec, xyz=tuple(float(v) for v in np.add(spec.xyz, off)))])
    endpoint, site = f"tcp/127.0.0.1:{free_port()}", f"contacts{free_port()}"
    ks = KeySpace(site)
    control = control_node(site, rig.robot, rig.robot, task_file, connect=(endpoint,), autostart=True,
                           predictor={"belief": str(belief)})
    control["modules"] += [
        {"name": "cues", "type": "contact_cues", "robot": rig.robot, "params": {"arm": rig.arm, "rate_hz": 200.0}},
        {"name": "model", "type": "contactflow.embodiments.modules.model_publisher:RobotModelPublisher",
         "robot": rig.robot, "params": {"rate_hz": 50.0}},
        {"name": "simulator", "type": "simulator_support_hypotheses", "robot": rig.robot,
         "params": {"robot": rig.robot, "dilate": POSE_SIGMA}}]
    # the range generator as the 3D vision computer runs it (thesis §6.3.3), on the world's depth stream
    vision = {"site": site, "node": f"vision3d_{rig.robot}", "robot": rig.robot, "clock": "lockstep",
              "zenoh": zenoh(connect=(endpoint,)),
              "modules": [{"name": "range", "type": "range_hypotheses",
                           "inputs": {"depth": ks.robot(rig.robot, "depth") if rig.camera else ks.camera("head"),
                                      "robot_model": f"{rig.robot}/model.robot_model"},
                           "params": {"robot": rig.robot, "table_z": TABLE_Z, "require_motion": False,
                                      "roi": [float(v) for v in (*(centre - ROI), *(centre + ROI))]}}]}
    fusion_node = f"fusion_{rig.robot}"
    generators = fused_generators(rig)
    every = max(generators, key=lambda m: len(generators[m]))
    keys, fusions = {}, []
    for mod, gens in generators.items():
        service = {"name": "fusion_" + "_".join(g.split("_")[0] for g in gens), "type": "contact_fusion",
                   "params": {"robot": rig.robot, "sources": f"{rig.robot}/*", "generators": list(gens)}}
        if mod == every:
            keys[mod] = ks.fused(rig.robot, "contacts")
        else:
            own = {port: ks.output(rig.robot, fusion_node, service["name"], port) for port in ("hypotheses", "contacts", "events")}
            service["outputs"], keys[mod] = own, own["contacts"]
        fusions.append(service)
    fusion = {"site": site, "node": fusion_node, "robot": rig.robot, "clock": "lockstep", "zenoh": zenoh(connect=(endpoint,)),
              "modules": fusions}
    w = world_node(site, cell, listen=endpoint, wait_for=(control["node"], fusion_node, vision["node"]),
                   ground_truth_hz=0.0, contacts_hz=200.0, camera_hz=CAMERA_HZ)
    started, watch = start_nodes(folder, [w, fusion, vision, control], site, endpoint)
    streams = _Streams(watch.t, keys, ks.evaluation(rig.robot, "true_contacts"), spec.name, ks.hypotheses(rig.robot))
    try:
        task = f"{control['node']}/task"
        if not wait_for(lambda: watch.outcome(task) is not None, 120.0 * len(dirs)):
            raise TimeoutError(f"bench contacts: the touches of {name} still ran after {120 * len(dirs)} s: "
                               f"{watch.sequence()[-10:]}")
        wait_for(lambda: False, 0.5)  # the last contact lists on their way
        fused, truth, clouds = streams.take()
        windows = _windows(watch.task_progress(), watch.messages(), len(dirs))
    finally:
        streams.close()
        stop_nodes(started, watch)
    span = max(truth[-1][0] - truth[0][0], 1e-9) if truth else float("nan")  # s of simulated time the world ran
    feeds = {"simulated_s": span, "clouds": clouds,
             "cycles_per_s": {mod: len(lists) / span for mod, lists in fused.items()}}
    return [{"object": name, "direction": d.tolist(), **judge_touch(win, fused, truth)}
            for d, win in zip(dirs, windows, strict=True)], feeds


def evaluate_runtime(touches: list[dict]) -> dict:
    """Table 4.1's figures of the runtime touches, per modality."""
    rows = {}
    reached = [t for t in touches if t["truth"] is not None]
    for mod in MODALITIES:
        hits = [t["modalities"][mod] for t in reached if t["modalities"].get(mod)]
        eps, sig = [h["eps"] for h in hits], [h["sigma"] for h in hits]
        rows[mod] = {"detected": len(hits), "touches": len(reached), "rate": 100.0 * len(hits) / max(len(reached), 1),
                     "ci95": [100.0 * b for b in wilson(len(hits), len(reached))],
                     "eps_cm": 100.0 * float(np.mean(eps)) if eps else float("nan"),
                     "eps_std_cm": 100.0 * float(np.std(eps)) if eps else float("nan"),
                     "sigma_cm": 100.0 * float(np.mean(sig)) if sig else float("nan"),
                     "delay_ms": 1000.0 * float(np.median([h["delay"] for h in hits])) if hits else float("nan")}
    return rows


def evaluate(touches: list[Touch], cparams: CondensationParams) -> dict:
    rows = {}
    for mod, sources in MODALITIES.items():
        eps, sig, detected, total = [], [], 0, 0
        for t in touches:
            if t.truth is None:
                continue
            total += 1
            integ = Integrator()
            for s in sources:
                integ.offer(s, t.clouds.get(s, Hypotheses.empty()), 0.0)
            contacts = condense(integ.cycle(0.0), cparams)
            if not contacts:
                continue
            best = min(contacts, key=lambda c: float(np.linalg.norm(c.location - t.truth)))
            detected += 1
            eps.append(float(np.linalg.norm(best.location - t.truth)))
            sig.append(best.sigma)
        rows[mod] = {
            "detected": detected, "touches": total, "rate": 100.0 * detected / max(total, 1),
            "ci95": [100.0 * b for b in wilson(detected, total)],
            "eps_cm": 100.0 * float(np.mean(eps)) if eps else float("nan"),
            "eps_std_cm": 100.0 * float(np.std(eps)) if eps else float("nan"),
            "sigma_cm": 100.0 * float(np.mean(sig)) if sig else float("nan"),
            "thesis": dict(zip(("rate", "eps_cm", "sigma_cm"), THESIS[mod], strict=True)) if mod in THESIS else None,
        }
    return rows


def _plot(touches: list[Touch], path: pathlib.Path, cparams: CondensationParams) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [t for t in touches if t.truth is not None][:4]
    if not shown:
        return
    fig = plt.figure(figsize=(4 * len(shown), 4))
    for i, t in enumerate(shown):
        ax = fig.add_subplot(1, len(shown), i + 1, projection="3d")
        integ = Integrator()
        for s in MODALITIES["all + simulator"]:
            integ.offer(s, t.clouds.get(s, Hypotheses.empty()), 0.0)
        fused = integ.cycle(0.0)
        if len(fused):
            sc = ax.scatter(*fused.location.T, c=fused.likelihood, cmap="viridis", s=6, vmin=0, vmax=1)
            fig.colorbar(sc, ax=ax, shrink=0.5, label="H(x)")
        for j, c in enumerate(condense(fused, cparams)):
            ax.scatter(*c.location, color="red", s=60, label="detected" if j == 0 else None)
        ax.scatter(*t.truth, color="black", marker="x", s=60, label="truth")
        ax.set_title(f"{t.obj} {np.round(t.direction, 2).tolist()}", fontsize=8)
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _cells(r: dict | None) -> list[str]:
    """detected, ε, σ of one modality row."""
    if r is None:
        return ["-"] * 3
    return [rate_text(r["detected"], r["touches"]), f"{r['eps_cm']:.2f} ±{r['eps_std_cm']:.2f}",
            f"{r['sigma_cm']:.2f}"]


def _run_rig(rig: Rig, quick: bool, executors: tuple[str, ...], out_dir: pathlib.Path,
             cparams: CondensationParams) -> tuple[dict, dict[str, dict]]:
    """One rig's touches with each executor: its part of the summary and its rows per executor."""
    rng = np.random.default_rng(0)
    specs = object_specs(rig)
    objects = ["box"] if quick else list(specs)
    dirs = directions(n_az=3, elevations=rig.elevations[:1]) if quick else directions(elevations=rig.elevations)
    per: dict[str, dict] = {}
    part: dict = {"rig": dataclasses.asdict(rig), "objects": objects, "directions": len(dirs)}
    if "local" in executors:
        t0 = time.time()
        touches: list[Touch] = []
        with Progress(transient=True) as progress:
            task = progress.add_task(f"{rig.robot}: touches", total=len(objects) * len(dirs))
            for name in objects:
                touches.extend(run_object(name, specs[name], rig, dirs, rng, progress, task))
        per["local"] = evaluate(touches, cparams)
        part.update({
            "touches": len(touches), "missed_touches": sum(t.truth is None for t in touches),
            "seconds": time.time() - t0, "modalities": per["local"],
            "per_touch": [{"object": t.obj, "direction": t.direction,
                           "truth": None if t.truth is None else t.truth.tolist(),
                           "hypotheses": {k: len(v) for k, v in t.clouds.items()}} for t in touches]})
        _plot(touches, out_dir / f"contacts_{rig.robot}.png", cparams)
    if "runtime" in executors:
        t0 = time.time()
        rt: list[dict] = []
        feeds: dict[str, dict] = {}
        rt_rng = np.random.default_rng(0)  # the predictor's belief of each object, whether the local run drew first
        with tempfile.TemporaryDirectory(prefix="bench-contacts-") as d, Progress(transient=True) as progress:
            task = progress.add_task(f"{rig.robot}: touches on the runtime", total=len(objects))
            for name in objects:
                touched, feeds[name] = run_object_runtime(name, specs[name], rig, dirs, pathlib.Path(d) / name, rt_rng)
                rt += touched
                progress.advance(task)
        per["runtime"] = evaluate_runtime(rt)
        part["runtime"] = {"touches": len(rt), "missed_touches": sum(t["truth"] is None for t in rt),
                           "seconds": time.time() - t0, "modalities": per["runtime"], "feeds": feeds, "per_touch": rt}
    return part, per


def run(out_dir: pathlib.Path, quick: bool = False, rig: str = "both", executor: str = "local") -> dict:
    """Table 4.1 with each rig (``both``: tombatossals' Allegro hand, the thesis's, and melfa's gripper beside it)
    and each executor, side by side; writes ``contacts.json``, ``contacts.md`` and ``contacts_<robot>.png``."""
    from contactflow.nodes.params import ParamError

    if executor not in EXECUTORS:
        raise ParamError(f"bench contacts: --executor {executor!r} is not one of {list(EXECUTORS)}")
    if rig not in (*RIGS, "both"):
        raise ParamError(f"bench contacts: --rig {rig!r} is not one of {[*RIGS, 'both']}")
    executors = ("local", "runtime") if executor == "both" else (executor,)
    rigs = tuple(RIGS) if rig == "both" else (rig,)
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cparams = CondensationParams()
    summary: dict = {"benchmark": "contacts", "quick": quick, "executor": executor, "rigs": {},
                     "goal": {"fused_detection_pct": 95.0, "fused_eps_cm": 2.0}}
    per: dict[tuple[str, str], dict] = {}
    for r in rigs:
        summary["rigs"][r], rows = _run_rig(RIGS[r], quick, executors, out_dir, cparams)
        per.update({(r, ex): row for ex, row in rows.items()})
    columns = [(r, ex) for r in rigs for ex in executors]

    def label(c: tuple[str, str]) -> str:  # the rig always (which hand touched), the executor where there are two
        return f" ({c[0]}, {c[1]})" if len(executors) > 1 else f" ({c[0]})"

    table = Table(title="Table 4.1 in simulation: contact detection per modality (detected: of the touches, "
                        "each an independent approach; [95 % Wilson interval])")
    table.add_column("modality", justify="right")
    for c in columns:
        for col in ("detected", "ε (cm)", "σ (cm)"):
            table.add_column(col + label(c), justify="right")
    for col in ("thesis detected", "thesis ε", "thesis σ"):
        table.add_column(col, justify="right")
    head = " | ".join(f"{col}{label(c)}" for c in columns for col in ("detected", "ε (cm)", "σ (cm)"))
    md = [f"| modality | {head} | thesis detected | thesis ε (cm) | thesis σ (cm) |",
          "|---|" + "---|" * (3 * len(columns) + 3)]
    for mod in MODALITIES:
        th = THESIS.get(mod)
        cells = [mod, *(x for c in columns for x in _cells(per[c].get(mod))),
                 *((f"{th[0]:.1f} %", f"{th[1]:.2f}", f"±{th[2]:.2f}") if th else ("-",) * 3)]
        table.add_row(*cells)
        md.append("| " + " | ".join(cells) + " |")
    Console().print(table)
    (out_dir / "contacts.md").write_text("\n".join(md) + "\n")
    (out_dir / "contacts.json").write_text(json.dumps(summary, indent=2))
    return summary
