"""Benchmark of thesis Tables 3.4-3.5: the unscrew primitive with and without its tactile re-centring, on eight bottles.

The protocol of §3.4.2 on the simulated tombatossals, run by one of two executors (``--executor``; ``both`` side by
side). ``local``: a screw bottle stands held on the table (its body fixed, standing in for the other hand), in this
process, and the Kinect finds its cap (the centroid of the top of
the bottle's points, "assumed to be the cap"), the right hand goes over it and the unscrew primitive
pinches, twists and pulls until the cap comes off or its cycles run out. Table 3.4: every bottle, the
cap approach as vision gives it; Table 3.5: one bottle (the thesis's most difficult, object 2) with a
uniform ±1.5 cm error added to the approach. Each configuration runs with the re-centring off and on, the
same seeds side by side. Judged from the cap's joints (ground truth): the cap is unscrewed when its thread
let go, removed when it also came off the neck in the fingers (the thesis's success also put the cap on the
table; the simulated cap stays on its lift joint, 10 cm of travel, so removed is as far as it goes). Every
trial draws its own approach error, bottle placement (±5 mm), camera and sensor noise.

``runtime``: the whole task of Fig. 3.18 as deployed (``embodiments/tasks/unscrew.yaml`` on a world node and
tombatossals' control node over zenoh): the bottle stands free where the ``open_bottle`` cell puts it (±5 mm), the
left hand grasps it from the side, lifts it to the vantage pose and holds it with force control while the right hand
unscrews the cap the Kinect found. Judged from the world's ground truth (bottle and cap poses): success = the task
succeeded, the cap is 3 cm or more off the neck along the bottle's axis and the bottle never tilted past
``TOPPLED_DEG``; unscrewed = the cap turned its thread's turns on the body. Writes ``unscrew.json``, ``unscrew.md``
and ``unscrew.png``.
"""

from __future__ import annotations

import json
import pathlib
import time
import zlib
from dataclasses import dataclass, replace
from itertools import product

import numpy as np

from contactflow.embodiments.parallel import run_all
from contactflow.embodiments.primitives.base import hand_pose_for, pose6, top_grasp_pose
from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner, outcome, run_primitive
from contactflow.embodiments.sim_robot import SimRobot, SimRobotParams
from contactflow.embodiments.world import ScrewBottleSpec, World, WorldParams
from contactflow.nodes.stats import rate, rate_text

ROBOT = "tombatossals"
ARM = "right"
BASE = (0.55, -0.3, 0.75)  # m, where the bottle stands on the table
NOISE = 0.015  # m, Table 3.5: uniform error on the approach to the cap, each horizontal axis
JITTER_XY = 0.005  # m, where each trial stands the bottle about BASE (the bottles were placed by hand)
NOISY_BOTTLE = "bottle2"  # the thesis's object 2, its most difficult, the one of Table 3.5
QUICK_BOTTLE = "bottle4"  # the shortest thread (--quick)
CAP_BAND = 0.004  # m, the top of the bottle's points taken as its cap's top face (a thicker band takes in the side the camera sees)
SELF_MARGIN = 0.02  # m, points this close to the robot model are the robot's (detect_objects' self filter)
CAP_DEPTH = 0.01  # m, the cap's centre below the top of those points (half a household cap's height)
MAX_CYCLES = 24  # pinch-twist-pull cycles before the primitive gives up (the longest thread took 14 twists)
TOPPLED_DEG = 30.0  # deg, a bottle tilted further (in the hand or on the table) has toppled
EXECUTORS = ("local", "runtime", "both")
THESIS = {"table_3_4": {"no": {"success": 0.875, "unscrewed": 0.938, "time": 156.47, "moves": 8.98},
                        "yes": {"success": 0.886, "unscrewed": 0.975, "time": 172.42, "moves": 10.06}},
          "table_3_5": {"no": {"success": 0.60, "unscrewed": 0.667, "time": 57.5, "moves": 3.4},
                        "yes": {"success": 0.80, "unscrewed": 0.867, "time": 66.9, "moves": 3.77}}}


def bottles() -> list[ScrewBottleSpec]:
    """Eight bottles of household sizes (Fig. 3.17 stand-ins): body, neck and cap sizes, threads of 0.3-0.7 turns
    (the thesis's 9-10 twists of 30 degrees) and their friction differ."""
    b = ScrewBottleSpec("bottle", xyz=BASE)
    return [
        replace(b, name="bottle1", thread_turns=0.5),
        replace(b, name="bottle2", cap_radius=0.015, cap_height=0.018, thread_turns=0.6, thread_friction=0.15),
        replace(b, name="bottle3", body_radius=0.04, body_height=0.18, cap_radius=0.018, thread_turns=0.6),
        replace(b, name="bottle4", body_radius=0.03, body_height=0.12, cap_radius=0.015, thread_turns=0.3,
                thread_friction=0.06),
        replace(b, name="bottle5", cap_radius=0.019, cap_height=0.024, thread_turns=0.7, thread_friction=0.12),
        replace(b, name="bottle6", body_height=0.2, neck_height=0.03, thread_turns=0.4, friction=0.8),
        replace(b, name="bottle7", body_radius=0.045, body_height=0.1, cap_radius=0.017, thread_turns=0.55),
        replace(b, name="bottle8", cap_radius=0.015, cap_height=0.022, thread_turns=0.65, thread_damping=0.04),
    ]


@dataclass(frozen=True)
class Trial:
    bottle: str
    reactive: bool  # the tactile re-centring on
    noise: bool  # Table 3.5's ±1.5 cm approach error
    trial: int
    executor: str = "local"  # local: the fixed bottle in process; runtime: the bimanual task on world and control nodes


def _seed(t: Trial) -> int:
    # the same seed with the re-centring on and off: both face one approach error and one sensor noise
    return 1000 * t.trial + zlib.crc32(f"{t.bottle}/{t.noise}".encode()) % 997


def cap_estimate(robot: SimRobot, spec: ScrewBottleSpec) -> np.ndarray:
    """Where the Kinect sees the cap: the centroid of the bottle's points within :data:`CAP_BAND` of their top,
    :data:`CAP_DEPTH` below the top (the visual pipeline of §6.3.3 on a region around the bottle, the robot's own points removed)."""
    pts = np.asarray(robot.camera("kinect").points)
    pts = pts[robot.spherical.clear_of(pts, SELF_MARGIN)]  # the arm and hand are not the bottle
    x, y, z = spec.xyz
    near = pts[(np.abs(pts[:, 0] - x) < 0.1) & (np.abs(pts[:, 1] - y) < 0.1) & (pts[:, 2] > z + 0.02)]
    if len(near) < 10:
        raise RuntimeError(f"bench unscrew: the Kinect sees {len(near)} points of {spec.name}")
    top = near[near[:, 2] > near[:, 2].max() - CAP_BAND]
    return np.array([*top[:, :2].mean(axis=0), near[:, 2].max() - CAP_DEPTH])


def _vec(T: np.ndarray) -> list[float]:
    v = pose6(T)
    return [v[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]


def run_trial(spec: ScrewBottleSpec, t: Trial, seed: int) -> dict:
    """One trial: the bottle held on the table where this trial stands it, the cap found by the Kinect, the hand over
    it (with the trial's approach error), the unscrew primitive to its outcome, judged from the cap's joints."""
    rng = np.random.default_rng(seed)
    dx, dy = rng.uniform(-JITTER_XY, JITTER_XY, 2)
    spec = replace(spec, xyz=(spec.xyz[0] + dx, spec.xyz[1] + dy, spec.xyz[2]))
    world = World(WorldParams())
    world.add_table()
    bottle = world.add_screw_bottle(spec)
    robot = SimRobot(world, ROBOT, params=SimRobotParams(seed=seed))
    runner = LocalPrimitiveRunner(robot)
    cap = cap_estimate(robot, spec)
    true_cap = bottle.cap_pose()[:3, 3]
    error = np.r_[rng.uniform(-NOISE, NOISE, 2), 0.0] if t.noise else np.zeros(3)
    T = hand_pose_for(ROBOT, top_grasp_pose(cap + error), "pinch")
    above = T.copy()
    above[2, 3] += 0.06
    for target in (above, T):
        moved = outcome(run_primitive(runner, "move_to", {"arm": ARM, "target": _vec(target)}, max_time=10.0))
        if moved.event != "success":
            return _result(t, bottle, None, f"approach: {moved.event} {moved.detail}", 0.0, cap, true_cap)
    t0 = robot.time
    end = outcome(run_primitive(runner, "unscrew", {"arm": ARM, "max_cycles": MAX_CYCLES, "recenter": t.reactive}, max_time=240.0))
    return _result(t, bottle, end, end.detail, robot.time - t0, cap, true_cap)


def _result(t: Trial, bottle, end, detail: str, duration: float, cap: np.ndarray, true_cap: np.ndarray) -> dict:
    unscrewed = bool(bottle.released)
    removed = unscrewed and bottle.cap_lift() >= 0.03 and end is not None and end.event == "success"
    values = dict(end.values) if end is not None else {}
    if removed:
        cause = ""
    elif end is None:
        cause = "approach"
    elif end.event == "success":
        cause = "reported removed, cap on the neck"
    elif "not removed" in detail and values.get("misses", 0) >= values.get("cycles", 0):
        cause = "every pinch missed the cap"
    elif "not removed" in detail:
        cause = "cycles ran out" + (" (thread let go)" if unscrewed else "")
    else:
        cause = str(end.event)
    return {"bottle": t.bottle, "reactive": t.reactive, "noise": t.noise, "trial": t.trial, "success": removed,
            "unscrewed": unscrewed, "cause": cause, "event": str(end.event) if end is not None else "", "detail": detail,
            "time": duration, "twists": int(values.get("twists", 0)), "corrections": int(values.get("corrections", 0)),
            "misses": int(values.get("misses", 0)),
            "turned_deg": float(np.rad2deg(bottle.cap_angle())), "lift": bottle.cap_lift(),
            "vision_error": float(np.linalg.norm(cap[:2] - true_cap[:2]))}


def run_trial_runtime(spec: ScrewBottleSpec, t: Trial, seed: int) -> dict:
    """One trial of the bimanual task on the runtime: a world node with the free bottle (placed as this trial
    draws) and tombatossals' control node running ``open_bottle`` in lockstep, in this process."""
    import tempfile

    from contactflow.embodiments.layout import control_node, run_cell, world_node, write_cell
    from contactflow.embodiments.scene_file import load_scene
    from contactflow.embodiments.tasks import TASKS_DIR
    from contactflow.nodes.procs import free_port

    rng = np.random.default_rng(seed)
    dx, dy = rng.uniform(-JITTER_XY, JITTER_XY, 2)
    error = rng.uniform(-NOISE, NOISE, 2) if t.noise else np.zeros(2)
    x, y, z = load_scene("open_bottle").bottles[0].xyz
    spec = replace(spec, xyz=(x + dx, y + dy, z), fixed=False)
    with tempfile.TemporaryDirectory(prefix="unscrew-trial-") as d:
        folder = pathlib.Path(d)
        cell = write_cell(folder / "cell.yaml", ROBOT, [], [spec])
        endpoint, site = f"tcp/127.0.0.1:{free_port()}", f"unscrew{free_port()}"
        control = control_node(site, ROBOT, ROBOT, TASKS_DIR / "unscrew.yaml", connect=(endpoint,), autostart=True,
                               plan={"max_cycles": MAX_CYCLES, "recenter": t.reactive,
                                     "approach_error": [float(v) for v in error]})
        world = world_node(site, cell, listen=endpoint, wait_for=(control["node"],), seed=seed, ground_truth_hz=10.0)
        run = run_cell(folder, world, [control], endpoint, timeout=900.0)
    series = [(m.hdr.t_sim, dict(zip(m.names, m.poses.numpy(), strict=True))) for m in run.poses if spec.name in m.names]
    ends = {e.module.rsplit("/", 1)[-1]: e for e in run.messages if e.event in ("success", "failure", "error", "timeout")}
    return runtime_result(t, spec, series, ends, str(run.outcomes[ROBOT].event), run.wall_s)


def runtime_result(t: Trial, spec: ScrewBottleSpec, series: list[tuple[float, dict]], ends: dict, outcome_event: str,
                   wall: float) -> dict:
    """A runtime trial's record from the bottle's ground truth (``series``: (t, {name: pose}) in time order) and the
    modules' final events (``ends``: module name -> EventMsg)."""
    name = spec.name
    body0 = series[0][1][name]
    neck = body0[:3, :3].T @ (series[0][1][f"{name}_cap"][:3, 3] - body0[:3, 3])
    tilt = max(float(np.degrees(np.arccos(np.clip(p[name][2, 2], -1.0, 1.0)))) for _, p in series)
    rel = [p[name][:3, :3].T @ p[f"{name}_cap"][:3, :3] for _, p in series]  # the cap's turn on the body
    yaws = np.unwrap([np.arctan2(R[1, 0], R[0, 0]) for R in rel])
    turn = float(yaws[-1] - yaws[0])
    body, cap = series[-1][1][name], series[-1][1][f"{name}_cap"]
    lift = float((body[:3, :3].T @ (cap[:3, 3] - body[:3, 3]) - neck)[2])
    unscrewed = turn >= 2.0 * np.pi * spec.thread_turns - 1e-3 or lift >= 0.005
    success = outcome_event == "success" and lift >= 0.03 and tilt < TOPPLED_DEG
    unscrew = ends.get("unscrew")
    values = dict(unscrew.values) if unscrew is not None else {}
    if success:
        cause = ""
    elif tilt >= TOPPLED_DEG:
        cause = "bottle toppled"
    elif unscrew is None:
        # the task's last failed step ended it (an approach that stopped short is tolerated: the grasp follows it)
        failed = max((e for n, e in ends.items() if n != "task" and e.event != "success"), key=lambda e: e.hdr.t_sim,
                     default=None)
        cause = f"{failed.module.rsplit('/', 1)[-1]}: {failed.event}" if failed is not None else "no outcome"
    elif values.get("misses", 0) >= values.get("cycles", 1) and unscrew.event != "success":
        cause = "every pinch missed the cap"
    elif unscrew.event != "success":
        cause = "cycles ran out" + (" (thread let go)" if unscrewed else "")
    else:
        cause = "reported removed, cap on the neck"
    return {"bottle": t.bottle, "reactive": t.reactive, "noise": t.noise, "trial": t.trial, "executor": t.executor,
            "success": success, "unscrewed": bool(unscrewed), "cause": cause, "event": outcome_event,
            "detail": unscrew.detail if unscrew is not None else "", "time": float(values.get("duration", 0.0)),
            "twists": int(values.get("twists", 0)), "corrections": int(values.get("corrections", 0)),
            "misses": int(values.get("misses", 0)), "turned_deg": float(np.degrees(turn)), "lift": lift,
            "max_tilt_deg": tilt, "wall_time": wall}


def _trial(t: Trial) -> dict:
    spec = next(b for b in bottles() if b.name == t.bottle)
    if t.executor == "runtime":
        return run_trial_runtime(spec, t, _seed(t))
    return {**run_trial(spec, t, _seed(t)), "executor": t.executor}


def rows_of(results: list[dict]) -> list[dict]:
    """Tables 3.4 and 3.5: per executor, table and re-centring, success, unscrewed, mean time and twists, failures by cause."""
    rows = []
    for executor, (table, noise), reactive in product(("local", "runtime"), (("table_3_4", False), ("table_3_5", True)),
                                                      (False, True)):
        rs = [r for r in results if r.get("executor", "local") == executor and r["noise"] == noise
              and r["reactive"] == reactive]
        if not rs:
            continue
        causes: dict[str, int] = {}
        for r in rs:
            if not r["success"]:
                causes[r["cause"]] = causes.get(r["cause"], 0) + 1
        rows.append({"executor": executor, "table": table, "reactive": "yes" if reactive else "no",
                     "success": rate(sum(r["success"] for r in rs), len(rs)),
                     "unscrewed": rate(sum(r["unscrewed"] for r in rs), len(rs)),
                     "time": float(np.mean([r["time"] for r in rs])),
                     "moves": float(np.mean([r["twists"] for r in rs])), "failures": causes})
    return rows


def run(out_dir: pathlib.Path, quick: bool = False, trials: int | None = None, jobs: int = 1,
        executor: str = "local") -> dict:
    from rich.console import Console
    from rich.progress import Progress
    from rich.table import Table

    from contactflow.nodes.params import ParamError

    if executor not in EXECUTORS:
        raise ParamError(f"bench unscrew: --executor {executor!r} is not one of {list(EXECUTORS)}")
    executors = ("local", "runtime") if executor == "both" else (executor,)
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    n = trials if trials is not None else (1 if quick else 10)
    # quick: the shortest thread, without approach error, re-centring off and on
    names = [QUICK_BOTTLE] if quick else [b.name for b in bottles()]
    noisy = 0 if quick else max(n, 15)  # Table 3.5 ran 15 trials
    plan = [Trial(b, r, False, k, ex) for ex in executors for b in names for k in range(n) for r in (False, True)]
    plan += [Trial(NOISY_BOTTLE, r, True, k, ex) for ex in executors for k in range(noisy) for r in (False, True)]
    t0 = time.perf_counter()
    with Progress(transient=True) as progress:
        task = progress.add_task("unscrew trials", total=len(plan))

        def done(_: int, r: dict) -> None:
            progress.update(task, advance=1, description=f"{r['executor']} {r['bottle']} {'noisy ' if r['noise'] else ''}"
                                                         f"re-centring {'on' if r['reactive'] else 'off'}")

        results = run_all(_trial, [(t,) for t in plan], jobs, done)
    rows = rows_of(results)
    per_bottle = {ex: {b: {("reactive" if r else "no correction"): sum(
        x["success"] for x in results if x["executor"] == ex and x["bottle"] == b and x["reactive"] == r and not x["noise"])
        for r in (False, True)} for b in names} for ex in executors}
    summary = {"benchmark": "unscrew", "robot": ROBOT, "executors": list(executors), "bottles": names,
               "trials_per_bottle": n, "noisy_trials": noisy,
               "quick": quick, "rows": rows, "per_bottle": per_bottle, "thesis": THESIS,
               "wall_time": time.perf_counter() - t0, "trials": results}
    (out_dir / "unscrew.json").write_text(json.dumps(summary, indent=1))
    table = Table(title=f"Unscrew (Tables 3.4-3.5): {len(names)} bottles x {n} trials" + (
        f", and {NOISY_BOTTLE} x {noisy} with ±{NOISE * 100:.1f} cm approach error" if noisy else "")
        + "; re-centring off and on, the same seeds")
    for col in ("executor", "table", "re-centring", "success [95 % interval]", "cap unscrewed", "time (s)", "twists", "failures",
                "thesis success / unscrewed / time / twists"):
        table.add_column(col)
    md = ["| executor | table | re-centring | success [95 % interval] | cap unscrewed | time (s) | twists | failures | thesis |",
          "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        th = THESIS[r["table"]][r["reactive"]]
        cells = [r["executor"] + (" (bimanual)" if r["executor"] == "runtime" else " (fixed bottle)"),
                 r["table"].replace("table_", "").replace("_", "."), r["reactive"],
                 rate_text(r["success"]["successes"], r["success"]["trials"]),
                 rate_text(r["unscrewed"]["successes"], r["unscrewed"]["trials"]), f"{r['time']:.1f}",
                 f"{r['moves']:.2f}", ", ".join(f"{k}: {v}" for k, v in r["failures"].items()) or "-",
                 f"{100 * th['success']:.1f} % / {100 * th['unscrewed']:.1f} % / {th['time']:.0f} s / {th['moves']:.2f}"]
        table.add_row(*cells)
        md.append("| " + " | ".join(cells) + " |")
    table.caption = f"{len(results)} independent trials, {summary['wall_time']:.0f} s wall"
    Console().print(table)
    (out_dir / "unscrew.md").write_text("\n".join(md) + "\n")
    _plot(results, out_dir / "unscrew.png")
    return summary


def _plot(results: list[dict], path: pathlib.Path) -> None:
    """Fig. 3.20: caps removed per bottle, re-centring off and on; Table 3.5's noisy bottle last."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = list(dict.fromkeys((r["bottle"], r["noise"], r["executor"]) for r in results))
    several = len({g[2] for g in groups}) > 1
    labels = [(f"{b}\n±{NOISE * 100:.1f} cm" if noise else b) + (f"\n{'bimanual' if ex == 'runtime' else 'fixed'}" if several else "")
              for b, noise, ex in groups]

    def pct(group: tuple[str, bool, str], reactive: bool) -> float:
        rs = [r for r in results if (r["bottle"], r["noise"], r["executor"]) == group and r["reactive"] == reactive]
        return 100.0 * sum(r["success"] for r in rs) / len(rs)

    x = np.arange(len(groups))
    fig, ax = plt.subplots(figsize=(max(8, 0.8 * len(groups)), 3.5))
    ax.bar(x - 0.2, [pct(g, False) for g in groups], 0.4, label="re-centring off", color="tab:green")
    ax.bar(x + 0.2, [pct(g, True) for g in groups], 0.4, label="re-centring on", color="tab:gray")
    ax.set_xticks(x, labels, fontsize="small")
    ax.set_ylabel("caps removed (%)")
    ax.set_ylim(0, 105)
    ax.legend(fontsize="small", loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
