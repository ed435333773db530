"""Benchmark of thesis Table 3.3: naive vs robust grasp, with and without approach-vector error, judged from ground truth.

Two executors run the same trials: ``local`` steps the primitives in this process against the
simulated robot; ``runtime`` runs each trial as the deployed system does, a world node (the
cell) and a control node whose task module runs the primitive modules over zenoh in lockstep
(``embodiments/tasks/grasp_trial.yaml``); ``both`` puts the two tables side by side.
"""

from __future__ import annotations

import functools
import json
import pathlib
import time
import zlib
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from contactflow.embodiments.parallel import run_all
from contactflow.embodiments.primitives.base import pose6
from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, outcome, run_primitive
from contactflow.embodiments.sim_robot import SimRobot, SimRobotParams
from contactflow.embodiments.world import (
    ObjectSpec,
    ShapeSpec,
    World,
    WorldParams,
    box,
    cylinder,
    sphere,
)
from contactflow.nodes.params import ParamError
from contactflow.nodes.stats import rate, rate_text

ROBOT = "tombatossals"
ARM = "right"
SPOT = (0.55, -0.3)
TABLE_Z = 0.75
JITTER_XY = 0.005  # m, each trial's object placement about where the vision system saw it (see jittered)
JITTER_YAW = np.deg2rad(5.0)  # rad
PRESHAPES = ("claw", "open")
"""The hand preshapes both controllers may close from (``--preshape``); the first is the bench's default. The claw is the
thesis's: its Barrett hand opened for a top grasp with the fingers toward the object (see the allegro's preshapes)."""



def objects() -> list[ObjectSpec]:
    """Ten objects of varied shape standing on the table at SPOT (thesis Fig. 3.14 stand-ins)."""
    x, y = SPOT
    z = TABLE_Z
    return [
        sphere("ball", 0.035, xyz=(x, y, z + 0.035), mass=0.1, friction=0.8),
        box("box", (0.055, 0.055, 0.07), xyz=(x, y, z + 0.035), mass=0.15, friction=0.8),
        ObjectSpec("car", (ShapeSpec("box", (0.10, 0.05, 0.03), (0.0, 0.0, 0.025)),
                           ShapeSpec("box", (0.05, 0.045, 0.025), (-0.015, 0.0, 0.05))),
                   mass=0.15, friction=0.8, xyz=(x, y, z + 0.001)),
        cylinder("cylinder", 0.03, 0.12, xyz=(x, y, z + 0.06), mass=0.2, friction=0.8),
        box("speaker", (0.075, 0.075, 0.11), xyz=(x, y, z + 0.055), mass=0.35, friction=0.8),
        ObjectSpec("spray", (ShapeSpec("cylinder", (0.025, 0.16), (0.0, 0.0, 0.08)),
                             ShapeSpec("box", (0.03, 0.02, 0.03), (0.01, 0.0, 0.175))),
                   mass=0.25, friction=0.8, xyz=(x, y, z + 0.001)),
        ObjectSpec("stapler", (ShapeSpec("box", (0.14, 0.04, 0.025), (0.0, 0.0, 0.0125)),
                               ShapeSpec("box", (0.12, 0.035, 0.025), (0.01, 0.0, 0.0375))),
                   mass=0.2, friction=0.8, xyz=(x, y, z + 0.001)),
        cylinder("tape", 0.045, 0.05, xyz=(x, y, z + 0.025), mass=0.1, friction=0.8),
        ObjectSpec("weight", (ShapeSpec("cylinder", (0.03, 0.05), (0.0, 0.0, 0.025)),
                              ShapeSpec("cylinder", (0.012, 0.04), (0.0, 0.0, 0.07))),
                   mass=0.5, friction=0.8, xyz=(x, y, z + 0.001)),
        box("wood", (0.12, 0.03, 0.03), xyz=(x, y, z + 0.015), mass=0.1, friction=0.8),
    ]


@dataclass(frozen=True)
class Trial:
    obj: str
    controller: str  # naive | robust
    error: bool
    trial: int
    preshape: str = PRESHAPES[0]  # the hand's preshape before the grasp closes, for both controllers


def perturb(approach: np.ndarray, rng: np.random.Generator, pos: float = 0.05, ang_deg: float = 15.0) -> np.ndarray:
    """Thesis §3.4.1 error: U(0, 5) cm per axis and U(0, 15)° per axis, each with a random sign."""
    T = approach.copy()
    T[:3, 3] += rng.uniform(0.0, pos, 3) * rng.choice([-1.0, 1.0], 3)
    rot = np.deg2rad(rng.uniform(0.0, ang_deg, 3) * rng.choice([-1.0, 1.0], 3))
    T[:3, :3] = T[:3, :3] @ Rotation.from_euler("xyz", rot).as_matrix()
    return T


def jittered(spec: ObjectSpec, rng: np.random.Generator) -> ObjectSpec:
    """``spec`` placed where this trial's object stands: U(-5, 5) mm in x and y, U(-5, 5) degrees about the
    vertical off where the vision system saw it (``vision_approach``, once per object). The trials are
    independent draws of the object's pose against one approach, as the thesis's objects were placed by
    hand; 5 mm is a Kinect voxel at the table (the cloud's 6 mm grid) and a third of the thesis's
    "more noise" case (±1.5 cm, §3.5.2)."""
    dx, dy = rng.uniform(-JITTER_XY, JITTER_XY, 2)
    yaw = rng.uniform(-JITTER_YAW, JITTER_YAW)
    return replace(spec, xyz=(spec.xyz[0] + dx, spec.xyz[1] + dy, spec.xyz[2]),
                   rpy=(spec.rpy[0], spec.rpy[1], spec.rpy[2] + yaw))


def draws(spec: ObjectSpec, approach: np.ndarray, t: Trial, seed: int) -> tuple[ObjectSpec, dict[str, float]]:
    """What trial ``t`` faces, drawn from ``seed`` alike in both executors: the object where it stands
    (:func:`jittered`, a random stream of its own, so the perturbations stay as they were) and the
    approach pose the arm moves to (``approach`` perturbed, with approach error)."""
    spec = jittered(spec, np.random.default_rng([seed, 1]))
    goal = perturb(approach, np.random.default_rng(seed)) if t.error else approach
    return spec, pose6(goal)


def scene(spec: ObjectSpec, seed: int = 0) -> tuple[World, SimRobot, LocalPrimitiveRunner]:
    """The table, ``spec`` and the robot, its sensor noise drawn from ``seed`` (as a world module seeds it)."""
    world = World(WorldParams())
    world.add_table()
    world.add_object(spec)
    robot = SimRobot(world, ROBOT, params=SimRobotParams(seed=seed))
    return world, robot, LocalPrimitiveRunner(robot)


def vision_approach(spec: ObjectSpec, preshape: str = PRESHAPES[0]) -> np.ndarray:
    """The approach vector of the visual system: detect_objects on the Kinect cloud (§3.4.1), for a hand closing from ``preshape``."""
    from contactflow.embodiments.primitives.base import matrix6

    _, _, runner = scene(spec)
    ev = outcome(run_primitive(runner, "detect_objects", {"standoff": 0.04, "preshape": preshape}, max_time=2.0))
    if ev.event != "success":
        raise RuntimeError(f"bench_grasp: the vision system did not find {spec.name}: {ev.detail}")
    v = ev.values
    return matrix6((v["x"], v["y"], v["z"], v["roll"], v["pitch"], v["yaw"]), "approach")


def verdict(z0: float, lifted: np.ndarray, held: np.ndarray, rel0: np.ndarray, rel1: np.ndarray) -> tuple[bool, str]:
    """Success = lifted 6 cm with the hand and not moving in it during a 1 s hold.

    ``lifted`` and ``held`` are the object's world poses when the lift ended and after the hold,
    ``rel0`` and ``rel1`` the same in a frame that moves with the hand.
    """
    if lifted[2, 3] - z0 < 0.06:
        return False, "not lifted"
    if held[2, 3] - z0 < 0.06:
        return False, "dropped during the hold"
    moved = float(np.linalg.norm(rel1[:3, 3] - rel0[:3, 3]))
    turned = float(np.linalg.norm(Rotation.from_matrix(rel0[:3, :3].T @ rel1[:3, :3]).as_rotvec()))
    if moved > 0.01 or turned > np.deg2rad(10):
        return False, f"moves in the hand ({moved * 100:.1f} cm, {np.rad2deg(turned):.0f} deg)"
    return True, "stable"


def judge(robot: SimRobot, name: str, z0: float) -> tuple[bool, str]:
    """:func:`verdict` on the simulated robot: the object's pose in the palm frame, the hold stepped here."""
    palm = robot.spec.hand(robot.spec.arm(ARM).hand).palm_link
    gt = robot.ground_truth().object_poses[name]
    if gt[2, 3] - z0 < 0.06:
        return False, "not lifted"
    rel0 = np.linalg.inv(robot.frame_pose(palm)) @ gt
    robot.step(1.0)
    gt1 = robot.ground_truth().object_poses[name]
    return verdict(z0, gt, gt1, rel0, np.linalg.inv(robot.frame_pose(palm)) @ gt1)


def run_trial(spec: ObjectSpec, approach: np.ndarray, t: Trial, seed: int,
              grasp_params: dict[str, object] | None = None) -> dict:
    """One trial: the object jittered, move to the (perturbed) approach, grasp, lift, judge; ``grasp_params``
    override the grasp's. ``seed`` draws the jitter, the perturbation and the robot's sensor noise."""
    spec, v = draws(spec, approach, t, seed)
    _, robot, runner = scene(spec, seed)
    t0 = robot.time
    move = outcome(run_primitive(runner, "move_to", {"arm": ARM, "target": [v[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]},
                                 max_time=10.0))
    z0 = float(robot.ground_truth().object_poses[spec.name][2, 3])
    grasp = outcome(run_primitive(runner, f"{t.controller}_grasp", {"arm": ARM, "pregrasp_type": t.preshape, **(grasp_params or {})},
                                 max_time=90.0))
    lift = outcome(run_primitive(runner, "lift", {"arm": ARM, "distance": 0.1, "watch_grasp": False}, max_time=6.0))
    ok, why = judge(robot, spec.name, z0)
    return {"object": t.obj, "controller": t.controller, "error": t.error, "trial": t.trial, "preshape": t.preshape, "success": ok,
            "why": why, "move": str(move.event), "grasp": str(grasp.event), "lift": str(lift.event),
            "grasp_values": {k: float(x) for k, x in grasp.values.items()}, "sim_time": robot.time - t0}


def _pose_at(poses: list, name: str, t: float) -> np.ndarray | None:
    """The object's ground-truth pose last published at or before simulated ``t``."""
    best = None
    for m in poses:
        if m.hdr.t_sim <= t + 1e-9 and name in m.names:
            best = m.poses.numpy()[m.names.index(name)]
    return best


def judge_poses(poses: list, name: str, t_lift: float, t_end: float) -> tuple[bool, str]:
    """:func:`verdict` from the world's ground-truth stream: the poses when the lift ended and after the
    1 s hold that follows it (the arm holds still, so the world frame moves with the hand)."""
    start = next((m.poses.numpy()[m.names.index(name)] for m in poses if name in m.names), None)
    lifted, held = _pose_at(poses, name, t_lift), _pose_at(poses, name, t_end)
    if start is None or lifted is None or held is None:
        return False, "no ground truth"
    return verdict(float(start[2, 3]), lifted, held, lifted, held)


def run_trial_runtime(spec: ObjectSpec, approach: np.ndarray, t: Trial, seed: int) -> dict:
    """One trial on the runtime: a world node (the cell with ``spec``) and tombatossals' control node in lockstep,
    in this process (a zenoh session each); the same jitter, perturbed approach and sensor noise as
    :func:`run_trial` for ``seed``."""
    import tempfile

    from contactflow.embodiments.layout import control_node, run_cell, world_node, write_cell
    from contactflow.embodiments.tasks import TASKS_DIR
    from contactflow.nodes.procs import free_port

    spec, v = draws(spec, approach, t, seed)
    with tempfile.TemporaryDirectory(prefix="grasp-trial-") as d:
        folder = pathlib.Path(d)
        cell = write_cell(folder / "cell.yaml", ROBOT, [spec])
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        site = f"grasp{free_port()}"
        control = control_node(site, ROBOT, ROBOT, TASKS_DIR / "grasp_trial.yaml", t.controller,
                               {"arm": ARM, "preshape": t.preshape, "approach": [v[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]},
                               connect=(endpoint,), autostart=True)
        world = world_node(site, cell, listen=endpoint, wait_for=(control["node"],), seed=seed, ground_truth_hz=50.0)
        run = run_cell(folder, world, [control], endpoint, timeout=600.0)
    final: dict = {}
    for e in run.messages:
        name = e.module.rsplit("/", 1)[-1]
        if e.event in ("success", "failure", "error", "timeout") and name in ("move_to", "robust_grasp", "naive_grasp", "lift"):
            final.setdefault(name, e)
    end = run.outcomes[ROBOT]
    lift = final.get("lift")
    ok, why = judge_poses(run.poses, spec.name, lift.hdr.t_sim if lift is not None else end.hdr.t_sim, end.hdr.t_sim)
    grasp = final.get(f"{t.controller}_grasp")
    return {"object": t.obj, "controller": t.controller, "error": t.error, "trial": t.trial, "preshape": t.preshape, "success": ok,
            "why": why, "move": str(final["move_to"].event) if "move_to" in final else "",
            "grasp": str(grasp.event) if grasp is not None else "", "lift": str(lift.event) if lift is not None else "",
            "grasp_values": dict(grasp.values) if grasp is not None else {}, "sim_time": run.sim_s, "wall_time": run.wall_s}


@functools.cache
def _approach(name: str, preshape: str) -> np.ndarray:
    return vision_approach(next(s for s in objects() if s.name == name), preshape)


def _seed(t: Trial) -> int:
    # same seed for naive and robust: both face the same object pose, perturbed approach vector and noise
    return 1000 * t.trial + zlib.crc32(t.obj.encode()) % 997


def _trial(t: Trial, grasp_params: dict[str, object] | None = None) -> dict:
    """One planned trial in this process (the approach of each object is computed once per process)."""
    spec = next(s for s in objects() if s.name == t.obj)
    return run_trial(spec, _approach(t.obj, t.preshape), t, seed=_seed(t), grasp_params=grasp_params)


def _runtime_trial(t: Trial) -> dict:
    """One planned trial on the runtime (world and control node in this worker process)."""
    spec = next(s for s in objects() if s.name == t.obj)
    return run_trial_runtime(spec, _approach(t.obj, t.preshape), t, seed=_seed(t))


EXECUTORS = ("local", "runtime", "both")


def rows_of(results: list[dict]) -> list[dict]:
    """Table 3.3's rows: stable grasps per controller, without and with approach error."""
    rows = []
    for c in ("naive", "robust"):
        for e in (False, True):
            rs = [r for r in results if r["controller"] == c and r["error"] == e]
            ok = sum(r["success"] for r in rs)
            rows.append({"controller": c + (" + error" if e else ""), "stable": ok, "failures": len(rs) - ok,
                         "success": rate(ok, len(rs))})
    return rows


def run(out_dir: pathlib.Path, quick: bool = False, trials: int | None = None, n_objects: int | None = None,
        jobs: int = 1, executor: str = "local", preshape: list[str] | None = None) -> dict:
    from rich.console import Console
    from rich.progress import Progress
    from rich.table import Table

    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    specs = objects()
    n_trials = trials if trials is not None else (1 if quick else 10)
    specs = specs[: n_objects if n_objects is not None else (1 if quick else len(specs))]
    if quick:
        specs = [s for s in objects() if s.name == "cylinder"]
    if executor not in EXECUTORS:
        raise ParamError(f"bench grasp: --executor {executor!r} is not one of {list(EXECUTORS)}")
    preshapes = tuple(dict.fromkeys(preshape or PRESHAPES[:1]))
    for ps in preshapes:
        if ps not in PRESHAPES:
            raise ParamError(f"bench grasp: --preshape {ps!r} is not one of {list(PRESHAPES)}")
    executors = ("local", "runtime") if executor == "both" else (executor,)
    # one column per executor and preshape, side by side; the last is the bench's result
    configs = [(ex, ps) for ps in preshapes for ex in executors]
    label = {c: ", ".join(x for x, n in zip(c, (len(executors), len(preshapes)), strict=True) if n > 1) or c[0]
             for c in configs}
    t_start = time.perf_counter()
    by_config: dict[tuple[str, str], list[dict]] = {}
    walls: dict[tuple[str, str], float] = {}
    with Progress(transient=True) as progress:
        for ex, ps in configs:
            plan = [Trial(s.name, c, e, k, ps) for s in specs for e in (False, True) for c in ("naive", "robust")
                    for k in range(n_trials)]
            task = progress.add_task(f"grasp trials ({ex}, {ps})", total=len(plan))

            def done(_: int, r: dict, task=task) -> None:
                progress.update(task, advance=1,
                                description=f"{r['object']} {r['controller']}{' + error' if r['error'] else ''}")

            t0 = time.perf_counter()
            by_config[ex, ps] = run_all(_trial if ex == "local" else _runtime_trial, [(t,) for t in plan], jobs, done)
            walls[ex, ps] = time.perf_counter() - t0
    results = by_config[configs[-1]]
    rows = rows_of(results)
    per_object = {s.name: {f"{c}{'+error' if e else ''}": sum(r["success"] for r in results
                                                               if r["object"] == s.name and r["controller"] == c and r["error"] == e)
                           for c in ("naive", "robust") for e in (False, True)} for s in specs}
    summary = {"benchmark": "grasp", "robot": ROBOT, "objects": [s.name for s in specs], "trials_per_condition": n_trials,
               "quick": quick, "rows": rows, "per_object": per_object, "wall_time": time.perf_counter() - t_start,
               "thesis": {"naive": 0.88, "robust": 0.99, "naive + error": 0.19, "robust + error": 0.59},
               "executor": configs[-1][0], "preshape": configs[-1][1], "trials": results,
               "executors": {ex: {"rows": rows_of(rs), "wall_time": walls[ex, ps], "trials": rs}
                             for (ex, ps), rs in by_config.items() if ps == configs[-1][1]},
               "preshapes": {ps: {"rows": rows_of(rs), "wall_time": walls[ex, ps], "trials": rs}
                             for (ex, ps), rs in by_config.items() if ex == configs[-1][0]}}
    (out_dir / "grasp.json").write_text(json.dumps(summary, indent=1))
    per = {c: rows_of(rs) for c, rs in by_config.items()}
    md = ["| controller | " + " | ".join(f"success [95 % interval] ({label[c]})" for c in configs) + " | thesis |",
          "|---|" + "---|" * len(configs) + "---|"]
    for i, r in enumerate(rows):
        cells = [rate_text(per[c][i]["stable"], per[c][i]["stable"] + per[c][i]["failures"]) for c in configs]
        md.append(f"| {r['controller']} | " + " | ".join(cells) + f" | {100 * summary['thesis'][r['controller']]:.0f}% |")
    (out_dir / "grasp.md").write_text("\n".join(md) + "\n")
    table = Table(title=f"Grasp benchmark (Table 3.3), {len(specs)} objects x {n_trials} independent trials "
                        "(own object pose, approach error and sensor noise each)")
    table.add_column("controller")
    for c in configs:
        table.add_column(f"stable, rate [95 % interval] ({label[c]})" if len(configs) > 1 else "stable, rate [95 % interval]")
    table.add_column("thesis")
    for i, r in enumerate(rows):
        cells = [rate_text(per[c][i]["stable"], per[c][i]["stable"] + per[c][i]["failures"]) for c in configs]
        table.add_row(r["controller"], *cells, f"{100 * summary['thesis'][r['controller']]:.0f}%")
    table.caption = f"hand preshape: {', '.join(preshapes)}" + (
        " | " + " | ".join(f"{label[c]}: {walls[c]:.0f} s wall" for c in configs) if len(configs) > 1 else "")
    Console().print(table)
    _plot({label[c]: per[c] for c in configs}, summary["thesis"], out_dir / "grasp.png")
    return summary


def _plot(columns: dict[str, list[dict]], thesis: dict, path: pathlib.Path) -> None:
    """Table 3.3 as bars: each column's rate per controller (executor, preshape) beside the thesis's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    rows = next(iter(columns.values()))
    x = np.arange(len(rows))
    width = 0.8 / (len(columns) + 1)
    for i, (name, rs) in enumerate(columns.items()):
        ax.bar(x + (i - len(columns) / 2) * width, [100 * r["success"]["rate"] for r in rs], width,
               label=f"simulation ({name})" if len(columns) > 1 else "simulation")
    ax.bar(x + len(columns) / 2 * width, [100 * thesis[r["controller"]] for r in rows], width, label="thesis (Table 3.3)")
    ax.set_xticks(x, [r["controller"] for r in rows])
    ax.set_ylabel("stable grasps (%)")
    ax.set_ylim(0, 105)
    ax.legend(fontsize="small", loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=len(columns) + 1)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
