"""Benchmark of the box grasp's catch zone: where a top grasp can start and still lift an object out of the empty-box scene.

``--executor local`` steps the attempt's primitives in this process; ``runtime`` runs it as a
world node and tombatossals' control node over zenoh in lockstep (``layout.CellSession``),
watching the task's progress stream and the world's ground truth; ``both`` runs every grasp on
both, side by side.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import time
from enum import StrEnum

import numpy as np

from contactflow.embodiments import bench_empty_box as box
from contactflow.embodiments.parallel import run_all
from contactflow.nodes.status import Event
from contactflow.nodes.taskengine import Progress, ProgressKind

OFFSETS = (-0.06, -0.04, -0.02, 0.0, 0.02, 0.04, 0.06)  # m, grasp-centre offsets from the object, per world axis
QUICK_OFFSETS = (-0.06, 0.0)
OBJECTS = ("can", "cube", "ball", "brick", "mug")  # the empty-box contents, in their maker order
# rad, top-grasp yaws: the exploration and vision strategies' (bench_empty_box.YAW) and the random strategy's
YAWS = (box.YAW, float(np.pi / 2))
# m from the box centre: beside each wall, where missed grasps leave objects (a can there is 0.5-1.5 cm off the wall)
WALL_SPOTS = ((-0.08, 0.0), (0.08, 0.0), (0.0, -0.10), (0.0, 0.10))
WALL_OBJECT = "can"
LIFTED = 0.08  # m, the object's rise above its start that counts as lifted out of the box
TRIAL_TIME = 40.0  # s of simulated time per trial


class Outcome(StrEnum):
    """How one trial ended (the first of these that happened)."""

    HELD = "held"  # the lift finished with the object out of the box: a grasp the strategies count as caught
    APPROACH_FAILED = "approach_failed"  # the hand never reached the start above the box
    GRASP_FAILED = "grasp_failed"  # the grasp ended without a hold (closed on nothing, arm blocked by a wall)
    LOST = "lost"  # the grasp reported a hold, but the object was not in the hand at the end of the lift
    LIFT_BLOCKED = "lift_blocked"  # the grasped thing did not come up (pinned under the fingers, or a wall)
    TIMEOUT = "timeout"  # nothing ended within TRIAL_TIME


def trial(name: str, dx: float, dy: float, yaw: float = box.YAW, at: tuple[float, float] = (0.0, 0.0)) -> dict:
    """One top grasp of ``yaw`` rad of the empty-box attempt (approach, grasp, lift) with its grasp centre at
    ``(dx, dy)`` m (world) from ``name``, alone in the box ``at`` m (world x, y) from its centre."""
    from contactflow.embodiments.primitives.base import hand_pose_for, top_grasp_pose
    from contactflow.embodiments.primitives.runner import LocalPrimitiveRunner
    from contactflow.embodiments.tasks import load

    specs = {o.name: o for o in box.contents(np.random.default_rng(0), len(OBJECTS))}
    if name not in specs:
        raise ValueError(f"catch zone: unknown object {name!r}; one of {', '.join(specs)}")
    cx, cy = box.BOX_CENTER[0] + at[0], box.BOX_CENTER[1] + at[1]
    obj = dataclasses.replace(specs[name], xyz=(cx, cy, specs[name].xyz[2]))
    robot = box.box_scene([obj])
    z0 = float(robot.ground_truth().object_poses[name][2, 3])
    tasks, _ = load()
    runner = LocalPrimitiveRunner(robot)
    ended: dict[str, object] = {}

    def watch(p: Progress) -> None:
        if not ended and p.kind is ProgressKind.EVENT and p.event is not None and _ending(p.node, p.event):
            ended.update(node=p.node, event=p.event, detail=p.detail)

    start = hand_pose_for(box.ROBOT, top_grasp_pose((cx + dx, cy + dy, box.BOTTOM + 0.16), yaw))
    target = box.task_params("random", 0)["target"]
    module = runner.host_task(tasks["box_attempt"], {"arm": box.ARM, "approach": box.vec6(start), "target": target},
                              tasks, watch)
    t0 = robot.time
    while not module.engine.done(module.run_id) and not ended and robot.time - t0 < TRIAL_TIME:
        runner.advance()
        robot.step(0.005)
    end = dict(ended)  # the trial's end, before the cancel below reports its own
    if not module.engine.done(module.run_id):
        module.engine.cancel(module.run_id, "trial over")
    runner.end_task(module)
    rise = float(robot.ground_truth().object_poses[name][2, 3]) - z0
    return {"object": name, "yaw": yaw, "at": list(at), "dx": dx, "dy": dy, "outcome": _outcome(end, rise), "rise": rise,
            "node": end.get("node", ""), "detail": end.get("detail", ""), "time": robot.time - t0, "executor": "local"}


def _ending(node: str, event: Event) -> bool:
    """The progress event that ends a trial: the approach or grasp failing, or the lift ending."""
    if node not in ("approach", "grasp", "lift") or (event is Event.SUCCESS and node != "lift"):
        return False
    return event in (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.TIMEOUT, Event.GRASP_LOST)


def trial_runtime(name: str, dx: float, dy: float, yaw: float = box.YAW, at: tuple[float, float] = (0.0, 0.0)) -> dict:
    """:func:`trial` on the runtime: the same attempt task run by tombatossals' control node against a world node."""
    import tempfile

    from contactflow.embodiments.layout import CellSession
    from contactflow.embodiments.primitives.base import hand_pose_for, top_grasp_pose
    from contactflow.embodiments.tasks import TASKS_DIR

    specs = {o.name: o for o in box.contents(np.random.default_rng(0), len(OBJECTS))}
    if name not in specs:
        raise ValueError(f"catch zone: unknown object {name!r}; one of {', '.join(specs)}")
    cx, cy = box.BOX_CENTER[0] + at[0], box.BOX_CENTER[1] + at[1]
    obj = dataclasses.replace(specs[name], xyz=(cx, cy, specs[name].xyz[2]))
    start = hand_pose_for(box.ROBOT, top_grasp_pose((cx + dx, cy + dy, box.BOTTOM + 0.16), yaw))
    plan = {"arm": box.ARM, "approach": box.vec6(start), "target": box.task_params("random", 0)["target"]}
    ended: dict[str, object] = {}
    with tempfile.TemporaryDirectory(prefix="catch-zone-") as d, \
            CellSession(pathlib.Path(d), [box.container(), obj], box.ROBOT, TASKS_DIR / "thesis.yaml", "box_attempt",
                        plan, ground_truth_hz=50.0) as cell:
        now = 0.0
        while not ended and now < TRIAL_TIME and cell.outcome() is None:
            time.sleep(0.1)
            for m in cell.progress():
                if m.kind == str(ProgressKind.EVENT) and m.event and _ending(m.node, Event(m.event)):
                    ended = {"node": m.node, "event": Event(m.event), "detail": m.detail, "t": m.hdr.t_sim}
                    break
            poses = cell.poses()
            now = poses[-1].hdr.t_sim if poses else 0.0
        poses = cell.poses()
    track = [(m.hdr.t_sim, float(m.poses.numpy()[m.names.index(name)][2, 3])) for m in poses if name in m.names]
    t_end = float(ended.get("t", now))
    rise = next((z for t, z in reversed(track) if t <= t_end + 1e-9), track[-1][1]) - track[0][1] if track else 0.0
    return {"object": name, "yaw": yaw, "at": list(at), "dx": dx, "dy": dy, "outcome": _outcome(ended, rise), "rise": rise,
            "node": ended.get("node", ""), "detail": ended.get("detail", ""), "time": t_end, "executor": "runtime"}


def _outcome(ended: dict, rise: float) -> Outcome:
    if not ended:
        return Outcome.TIMEOUT
    node, event = ended["node"], ended["event"]
    if node == "approach":
        return Outcome.APPROACH_FAILED
    if node == "grasp":
        return Outcome.GRASP_FAILED
    if event is Event.SUCCESS:
        return Outcome.HELD if rise >= LIFTED else Outcome.LOST
    return Outcome.LOST if event is Event.GRASP_LOST else Outcome.LIFT_BLOCKED


def summarize(trials: list[dict], offsets: tuple[float, ...]) -> list[dict]:
    """Per object, place in the box and yaw: held trials, the catch area (held cells x cell area, cm²) and the
    held cells' mean offset."""
    step = float(np.min(np.diff(sorted(offsets)))) if len(offsets) > 1 else 0.0
    rows = []
    for key in dict.fromkeys(_case(t) for t in trials):
        name, at, yaw, executor = key
        ts = [t for t in trials if _case(t) == key]
        held = [t for t in ts if t["outcome"] == Outcome.HELD]
        counts = {o.value: sum(t["outcome"] == o for t in ts) for o in Outcome}
        centre = [float(np.mean([t[k] for t in held])) for k in ("dx", "dy")] if held else None
        rows.append({"object": name, "at": list(at), "yaw": yaw, "executor": executor, "trials": len(ts), "held": len(held),
                     "area_cm2": len(held) * (100 * step) ** 2, "held_centre": centre, "outcomes": counts})
    return rows


def _case(t: dict) -> tuple[str, tuple[float, ...], float, str]:
    return t["object"], tuple(t.get("at", (0.0, 0.0))), t.get("yaw", box.YAW), t.get("executor", "local")


EXECUTORS = ("local", "runtime", "both")


def _trial(executor: str, name: str, dx: float, dy: float, yaw: float, at: tuple[float, float]) -> dict:
    return (trial if executor == "local" else trial_runtime)(name, dx, dy, yaw, at)


def _where(row: dict) -> str:
    x, y = row["at"]
    return "centre" if x == 0.0 and y == 0.0 else f"{100 * x:+.0f}, {100 * y:+.0f} cm"


def _centre(row: dict) -> str:
    c = row["held_centre"]
    return "-" if c is None else f"{100 * c[0]:+.1f}, {100 * c[1]:+.1f}"


def run(out_dir: pathlib.Path, quick: bool = False, jobs: int = 1, executor: str = "local") -> dict:
    """Every object alone at the box centre and the can beside each wall, a top grasp of each strategy yaw from
    each grid offset; ``jobs`` worker processes; ``executor``: local, runtime or both (every grasp on both)."""
    from rich.console import Console
    from rich.progress import Progress as Bar
    from rich.table import Table

    from contactflow.nodes.params import ParamError

    if executor not in EXECUTORS:
        raise ParamError(f"bench catch-zone: --executor {executor!r} is not one of {list(EXECUTORS)}")
    executors = ("local", "runtime") if executor == "both" else (executor,)
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    offsets, yaws = (QUICK_OFFSETS, YAWS[:1]) if quick else (OFFSETS, YAWS)
    cases = [(OBJECTS[0], (0.0, 0.0))] if quick else \
        [(name, (0.0, 0.0)) for name in OBJECTS] + [(WALL_OBJECT, at) for at in WALL_SPOTS]
    plan = [(ex, name, dx, dy, yaw, at) for ex in executors for yaw in yaws for name, at in cases
            for dx in offsets for dy in offsets]
    t_start = time.perf_counter()
    with Bar(transient=True) as bar:
        job = bar.add_task(f"catch zone ({len(plan)} grasps)", total=len(plan))
        trials = run_all(_trial, plan, jobs, lambda _, r: bar.update(
            job, advance=1, description=f"{r['object']} at {r['dx']:+.2f}, {r['dy']:+.2f}: {r['outcome']}"))
    rows = summarize(trials, offsets)
    summary = {"benchmark": "catch_zone", "robot": box.ROBOT, "executors": list(executors), "yaws": list(yaws),
               "offsets": list(offsets),
               "lifted": LIFTED, "rows": rows, "wall_time": time.perf_counter() - t_start,
               "trials": [{**t, "outcome": str(t["outcome"])} for t in trials]}
    (out_dir / "catch_zone.json").write_text(json.dumps(summary, indent=1))
    kinds = [o.value for o in Outcome if o is not Outcome.HELD]
    md = ["| object | in the box at | yaw (rad) | executor | held | catch area (cm²) | held cells' mean offset (cm) | "
          + " | ".join(kinds) + " |", "|---|---|---|---|---|---|---|" + "---|" * len(kinds)]
    for r in rows:
        md.append(f"| {r['object']} | {_where(r)} | {r['yaw']:.2f} | {r['executor']} | {r['held']}/{r['trials']} | {r['area_cm2']:.0f} | "
                  f"{_centre(r)} | " + " | ".join(str(r["outcomes"][k]) for k in kinds) + " |")
    x0, y0, x1, y1 = box.task_params("random", 0)["area"]
    md.append(f"\nGrasp centre offsets {', '.join(f'{100 * o:+.0f}' for o in offsets)} cm per world axis from the "
              f"object; the random strategy draws its grasp centres over {1e4 * (x1 - x0) * (y1 - y0):.0f} cm² of "
              "the box.")
    (out_dir / "catch_zone.md").write_text("\n".join(md) + "\n")
    table = Table(title=f"Catch zone of the box grasp ({box.ROBOT}), {len(offsets)}x{len(offsets)} offsets")
    for col in ("object", "at", "yaw", "executor", "held", "area (cm²)", "mean offset (cm)", "grasp failed", "lost",
                "lift blocked"):
        table.add_column(col)
    for r in rows:
        o = r["outcomes"]
        table.add_row(r["object"], _where(r), f"{r['yaw']:.2f}", r["executor"], f"{r['held']}/{r['trials']}", f"{r['area_cm2']:.0f}",
                      _centre(r), str(o["grasp_failed"]), str(o["lost"]), str(o["lift_blocked"]))
    Console().print(table)
    _plot(trials, rows, offsets, yaws, out_dir / "catch_zone.png")
    return summary


def _plot(trials: list[dict], rows: list[dict], offsets: tuple[float, ...], yaws: tuple[float, ...],
          path: pathlib.Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    kinds = list(Outcome)
    colors = ["#2ca02c", "#7f7f7f", "#d62728", "#ff7f0e", "#9467bd", "#000000"]
    index = {round(o, 4): k for k, o in enumerate(offsets)}
    places = list(dict.fromkeys((r["object"], tuple(r["at"]), r["executor"]) for r in rows))
    several = len({p[2] for p in places}) > 1
    fig, axes = plt.subplots(len(yaws), len(places), figsize=(2.6 * len(places) + 1.2, 2.9 * len(yaws)), squeeze=False)
    cm = [100 * o for o in offsets]
    half = (cm[1] - cm[0]) / 2 if len(cm) > 1 else 1.0
    for r in rows:
        ax = axes[yaws.index(r["yaw"])][places.index((r["object"], tuple(r["at"]), r["executor"]))]
        grid = np.full((len(offsets), len(offsets)), np.nan)
        for t in trials:
            if _case(t) == (r["object"], tuple(r["at"]), r["yaw"], r["executor"]):
                grid[index[round(t["dy"], 4)], index[round(t["dx"], 4)]] = kinds.index(Outcome(t["outcome"]))
        ax.imshow(grid, origin="lower", cmap=ListedColormap(colors), vmin=-0.5, vmax=len(kinds) - 0.5,
                  extent=(cm[0] - half, cm[-1] + half, cm[0] - half, cm[-1] + half))
        on = f" [{r['executor']}]" if several else ""
        ax.set_title(f"{r['object']} ({_where(r)}){on}, yaw {r['yaw']:.2f}:\n{r['held']}/{r['trials']} held", fontsize=8)
        ax.set_xlabel("grasp centre dx (cm)")
    for row in axes:
        row[0].set_ylabel("dy (cm)")
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in colors]
    fig.legend(handles, [k.value for k in kinds], loc="center right", fontsize=7)
    fig.tight_layout(rect=(0, 0, 1 - 1.1 / fig.get_figwidth(), 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)
