"""Benchmark: Table 4.1 in simulation — contact detection rate and localisation per modality.

A hand touches a fixed object (box, cylinder, spray-bottle-like) from 15 approach
directions each (5 azimuths x 3 elevations) with a guarded move that stops when the wrist
F/T feels the touch. At the stop every generator runs on the simulated sensors: tactile
pads (eq. 4.6), wrist F/T (eq. 4.8-4.9, hand model from the spherical model), a head-like
depth camera above and behind the robot (the arm hides the object at the touch; the grid
built before the approach carries the knowledge) + occupancy grid (§4.4.4; the object is fixed, so the range
generator runs with ``require_motion=False``) and simulator prediction support (§4.5.2: a
prediction scene with the object displaced by N(0, 2 cm), robot posed at the measured
joints). The rig (robot, arm, hand) is a parameter; ``melfa`` (arm + parallel gripper with
two 5x8 pads) is the default because the Tombatossals Allegro hand currently passes through
objects in the simulator (no contact force; reported to the embodiments area). Per
modality the clouds are fused and condensed (threshold-cluster-centroid); a touch is
detected when a contact comes out, ε is the distance of the closest contact to the ground
truth (force-weighted mean of the simulator's true hand-object contact points, evaluation
only) and σ its spread. Touches where the hand never reached the object are left out, as
in the thesis. Writes ``contacts.json``, ``contacts.md`` and ``contacts.png``.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import time
from dataclasses import dataclass, field

import numpy as np
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

MODALITIES = {
    "tactile": ("tactile",),
    "force": ("force",),
    "range": ("range",),
    "all": ("tactile", "force", "range"),
    "all + simulator": ("tactile", "force", "range", "simulator"),
}
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
    turn: tuple[float, ...] = (1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0)  # rotation applied to the home ee orientation
    camera: str = ""  # the robot's own depth camera; "" = a fixed head-like camera above and behind


RIGS = {
    "melfa": Rig(),
    "tombatossals": Rig("tombatossals", "right", "right_hand", "right_palm_link",
                        ("right_palm_link", "right_link_"), (0.55, -0.30), (1.0, 0, 0, 0, 0, 1.0, 0, -1.0, 0),
                        "kinect"),
}
POSE_SIGMA = 0.02  # m, object pose error of the prediction scene (thesis §4.7)
PRESS_FORCE = 1.5  # N, wrist force at which the touch is recorded


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


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera pose (optical frame: x right, y down, z forward) at ``eye`` looking at ``target``."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = eye
    return T


def run_object(name: str, spec, rig: Rig, dirs: list[np.ndarray], rng: np.random.Generator, progress,
               task) -> list[Touch]:
    from contactflow.embodiments.registry import CameraSpec
    from contactflow.embodiments.sensors.camera import DepthCamera
    from contactflow.embodiments.sim_robot import SimRobot
    from contactflow.embodiments.world import World, WorldParams

    world = World(WorldParams(timestep=0.0025))
    world.add_table()
    world.add_object(spec)
    robot = SimRobot(world, rig.robot)
    arm = robot.arm(rig.arm)
    home_q = arm.q()
    home_T = arm.ee_pose()
    home_T[:3, :3] = np.asarray(rig.turn).reshape(3, 3) @ home_T[:3, :3]
    prediction = PredictionScene(spec, rig)
    centre = np.array([*rig.object_xy, TARGET_Z[name]])
    roi_lo, roi_hi = centre - [0.12, 0.12, 0.2], centre + [0.12, 0.12, 0.2]
    rparams = RangeParams(table_z=TABLE_Z, require_motion=False)
    # A head-like depth camera above and behind the robot, looking at the object.
    if rig.camera:
        def read_depth():
            return robot.camera(rig.camera)
    else:
        camera = DepthCamera(world, CameraSpec(name="head", link=""),
                               T_world_cam=look_at(np.array([-0.1, rig.object_xy[1], 1.45]), centre))

        def read_depth():
            return camera.read(robot.time)
    frame = read_depth()
    cam = frame.T_world_cam[:3, 3]
    obj_pts = segment_object(frame.points, robot.spherical.distance, rparams, roi_lo, roi_hi)
    touches = []
    for d in dirs:
        arm.move_joints(home_q)
        arm.wait(6.0)
        rng_gen = RangeGenerator(rparams)
        rng_gen.initialize(obj_pts, cam)
        start = home_T.copy()
        start[:3, 3] = centre - 0.13 * d
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
        touch.clouds["simulator"] = simulator_support(predicted, now, SimulatorParams())
    return touches


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
            "eps_cm": 100.0 * float(np.mean(eps)) if eps else float("nan"),
            "eps_std_cm": 100.0 * float(np.std(eps)) if eps else float("nan"),
            "sigma_cm": 100.0 * float(np.mean(sig)) if sig else float("nan"),
            "thesis": dict(zip(("rate", "eps_cm", "sigma_cm"), THESIS[mod], strict=True)),
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


def run(out_dir: pathlib.Path, quick: bool = False, rig: str = "melfa") -> dict:
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    the_rig = RIGS[rig]
    specs = object_specs(the_rig)
    objects = ["box"] if quick else list(specs)
    dirs = directions(n_az=3, elevations=(0.0,)) if quick else directions()
    cparams = CondensationParams()
    touches: list[Touch] = []
    t0 = time.time()
    with Progress(transient=True) as progress:
        task = progress.add_task("touches", total=len(objects) * len(dirs))
        for name in objects:
            touches.extend(run_object(name, specs[name], the_rig, dirs, rng, progress, task))
    rows = evaluate(touches, cparams)
    table = Table(title="Table 4.1 in simulation: contact detection per modality")
    for col in ("modality", "detected", "ε (cm)", "σ (cm)", "thesis detected", "thesis ε", "thesis σ"):
        table.add_column(col, justify="right")
    md = ["| modality | detected | ε (cm) | σ (cm) | thesis detected | thesis ε (cm) | thesis σ (cm) |",
          "|---|---|---|---|---|---|---|"]
    for mod, r in rows.items():
        th = r["thesis"]
        cells = [mod, f"{r['detected']}/{r['touches']} ({r['rate']:.1f} %)",
                 f"{r['eps_cm']:.2f} ±{r['eps_std_cm']:.2f}", f"{r['sigma_cm']:.2f}",
                 f"{th['rate']:.1f} %", f"{th['eps_cm']:.2f}", f"±{th['sigma_cm']:.2f}"]
        table.add_row(*cells)
        md.append("| " + " | ".join(cells) + " |")
    Console().print(table)
    (out_dir / "contacts.md").write_text("\n".join(md) + "\n")
    _plot(touches, out_dir / "contacts.png", cparams)
    summary = {
        "benchmark": "contacts", "quick": quick, "rig": dataclasses.asdict(the_rig), "objects": objects, "directions": len(dirs),
        "touches": len(touches), "missed_touches": sum(t.truth is None for t in touches),
        "seconds": time.time() - t0, "modalities": rows,
        "per_touch": [{"object": t.obj, "direction": t.direction,
                       "truth": None if t.truth is None else t.truth.tolist(),
                       "hypotheses": {k: len(v) for k, v in t.clouds.items()}} for t in touches],
        "goal": {"fused_detection_pct": 95.0, "fused_eps_cm": 2.0},
    }
    (out_dir / "contacts.json").write_text(json.dumps(summary, indent=2))
    return summary
