"""Benchmark: a robot takes objects another robot found by touch (thesis ch. 4 across robots, one contact map per cell).

The empty-box scene of Table 3.6 (a box of objects no camera is used on) as one cell with two
robots: melfa (a UR5 with a parallel gripper) across the table from tombatossals (the Allegro
hand). Per seed, on the runtime (world node, each robot's control node, the cell's contact map):

- **alone**: tombatossals explores the box by touch itself (``poke_box``: its closed hand comes
  down at a grid of spots), then takes the objects from the map its touches made
  (``empty_box_mapped``);
- **with map**: melfa explores the box by touch (``poke_box``), and tombatossals, started when
  melfa is done, takes the objects from the cell's map without exploring.

The cell's map is a ``cell_fusion`` module with a ``map_region`` over the box: the objects the
fused contacts of either robot touched there. Per run: tombatossals' grasp attempts and how they
ended (as ``bench empty-box`` tells them), its time
(sim s, from its start to the box found empty by the ground truth), success, and the map it
started taking from against the ground truth of that moment: objects localised (an estimate
within ``LOCALISED`` m in the plane), their mean error, estimates near no object.
"""

from __future__ import annotations

import json
import pathlib
import tempfile
import threading
import time
from typing import Any

import numpy as np

from contactflow.embodiments import bench_empty_box as box
from contactflow.embodiments.parallel import run_logged
from contactflow.embodiments.primitives.base import top_grasp_pose
from contactflow.nodes.stats import mean, mean_text, rate, rate_text

EXPLORER, EXPLORER_ARM = "melfa", "arm"  # robot A: explores, and takes nothing
TAKER = box.ROBOT  # robot B: takes the objects (its arm: box.ARM)
EXPLORER_BASE = (1.12, -0.32, 0.75, 0.0, 0.0, np.pi)  # m, rad: melfa across the table, the box 0.57 m in front of it
CELL = "box_cell"
VARIANTS = ("alone", "with_map")
PITCH = 0.04  # m between poke spots
QUICK_PITCH = 0.06  # m between poke spots in a quick run (one object): melfa's 2.2 cm wide gripper still lands on anything 2.4 cm across
POKE_YAW = 0.0  # rad, the poking hand's top-grasp yaw
POKE_RISE = 0.09  # m, the poking hand moves between spots this far above where it meets the bottom (objects are <= 7 cm)
LOCALISED = 0.03  # m, an object with a map estimate this close (in the plane) is localised
SPURIOUS = 0.05  # m, an estimate farther than this from every object is spurious
MAX_TIME = 900.0  # s of simulated time for the taker per run
MAX_ATTEMPTS = 40  # the taker's grasp attempts per run


def map_region() -> list[float]:
    """The cell map's region: inside the box walls (5 mm in), from 2 cm above its bottom (fingertips pressing on the
    bottom were placed up to 1.5 cm above it; the bottom is no object) to 8 cm above it (the objects are at most 7 cm tall); an object carried out of it is dropped from
    the map."""
    cx, cy = box.BOX_CENTER
    hx, hy = box.INNER[0] / 2 - 0.005, box.INNER[1] / 2 - 0.005
    return [cx - hx, cy - hy, box.BOTTOM + 0.02, cx + hx, cy + hy, box.BOTTOM + 0.08]


def poke_plan(robot: str, arm: str, home: tuple[float, float, float] | None = None, pitch: float = PITCH) -> dict:
    """``poke_box``'s params for ``robot``'s closed hand: a grid of spots at most ``pitch`` apart over the box bottom
    that keeps the hand's lowest part inside the walls, the height it moves at and where it meets the bottom;
    ``home``: where the hand goes after (default: back over the first spot)."""
    fp = box.hand_footprint(box.HEIGHT, robot, arm)
    x0, x1, y0, y1, floor = box.hand_range(fp, box.SWEEP_CLEARANCE, POKE_YAW)
    xs = np.linspace(x0, x1, max(2, int(np.ceil((x1 - x0) / pitch)) + 1))
    ys = np.linspace(y0, y1, max(2, int(np.ceil((y1 - y0) / pitch)) + 1))
    spots = [float(v) for i, x in enumerate(xs) for y in (ys if i % 2 == 0 else ys[::-1]) for v in (x, y)]
    height = floor + POKE_RISE
    start = box.vec6(top_grasp_pose((x0, ys[0], height), POKE_YAW))
    return {"arm": arm, "start": start, "spots": spots, "height": float(height), "floor": float(floor),
            "home": box.vec6(top_grasp_pose(home, POKE_YAW)) if home else start}


def take_plan() -> dict:
    """``empty_box_mapped``'s params for the taker: the cell's map, the box, the approaches and the place of the
    empty-box bench's strategies."""
    plan = box.task_params("vision", 0)
    return {"arm": box.ARM, "region": plan["walls"], "bottom": box.BOTTOM, "height": box.APPROACH_HEIGHT,
            "target": plan["target"], "walls": plan["walls"], "yaw": plan["yaw"]}


class _Map:
    """The cell's object map as it came (stamp, [(id, x, y, z)]), from a subscription on the key space."""

    def __init__(self, watch, ks) -> None:  # type: ignore[no-untyped-def]
        from contactflow.fusion.messages import ObjectMapMsg
        from contactflow.nodes.wire import decode

        self.lock = threading.Lock()
        self.seen: list[tuple[float, list[tuple[int, float, float, float]]]] = []

        def on(key: str, payload: bytes) -> None:
            m = decode(payload, ObjectMapMsg, key)
            with self.lock:
                self.seen.append((m.stamp, [(o.id, *o.location) for o in m.objects]))

        self.sub = watch.t.subscribe(ks.fused(CELL, "objects"), on)

    def at(self, t: float) -> list[tuple[int, float, float, float]]:
        """The map of the last cycle at or before ``t`` (sim s)."""
        with self.lock:
            return next((objs for stamp, objs in reversed(self.seen) if stamp <= t), [])


def localisation(estimates: list[tuple[int, float, float, float]], truth: dict[str, np.ndarray]) -> dict:
    """The map against the objects' true positions (names -> xyz): per object the nearest estimate's distance in
    the plane, how many are localised, the mean error of those, and the estimates near no object."""
    est = np.array([e[1:3] for e in estimates]).reshape(-1, 2)
    objs = {n: np.asarray(p[:2]) for n, p in truth.items()}
    nearest = {n: float(np.min(np.linalg.norm(est - p, axis=1))) if len(est) else float("inf") for n, p in objs.items()}
    hit = [d for d in nearest.values() if d <= LOCALISED]
    spurious = sum(1 for e in est if min((np.linalg.norm(e - p) for p in objs.values()), default=np.inf) > SPURIOUS)
    return {"estimates": len(est), "localised": len(hit), "objects": len(objs),
            "error": float(np.mean(hit)) if hit else None, "spurious": spurious,
            "nearest": {n: (d if np.isfinite(d) else None) for n, d in nearest.items()}}


def run_once(variant: str, seed: int, n_objects: int, max_attempts: int, max_time: float, pitch: float = PITCH) -> dict:
    """One run on the runtime, all nodes in this worker process (a zenoh session each); see the module docstring."""
    from contactflow.embodiments.layout import (
        cell_map_module,
        control_node,
        start_nodes,
        stop_nodes,
        world_node,
        write_cell,
    )
    from contactflow.embodiments.tasks import TASKS_DIR
    from contactflow.nodes.keys import KeySpace
    from contactflow.nodes.messages import Command, ControlReply, ControlRequest
    from contactflow.nodes.procs import free_port
    from contactflow.nodes.wire import decode, encode

    objs = box.contents(np.random.default_rng(seed), n_objects)
    names = [o.name for o in objs]
    mapped = variant == "with_map"
    robots: list[dict[str, Any]] = [{"name": TAKER}]
    if mapped:
        robots.append({"name": EXPLORER, "base": list(EXPLORER_BASE)})
    tasks = TASKS_DIR / "thesis.yaml"
    take = take_plan()
    if mapped:
        task, plan = "empty_box_mapped", take
    else:  # it explores first: the poke's height, and the take's as approach_height
        task = "poke_and_empty_box"
        plan = {**{k: v for k, v in take.items() if k != "height"}, **poke_plan(TAKER, box.ARM, pitch=pitch),
                "approach_height": take["height"]}
    with tempfile.TemporaryDirectory(prefix="shared-contacts-") as d:
        folder = pathlib.Path(d)
        endpoint, site = f"tcp/127.0.0.1:{free_port()}", f"shared{free_port()}"
        # the taker chooses from the cell's map
        cell_map = {"choose_mapped": {"objects": KeySpace(site).fused(CELL, "objects")}}
        controls = [control_node(site, TAKER, TAKER, tasks, task, plan, connect=(endpoint,), autostart=not mapped,
                                 contacts=True, inputs=cell_map)]
        controls[0]["modules"].append(cell_map_module(CELL, tuple(r["name"] for r in robots), map_region=map_region()))
        if mapped:
            home = (box.BOX_CENTER[0] + 0.3, box.BOX_CENTER[1], box.BOTTOM + 0.3)
            controls.append(control_node(site, EXPLORER, EXPLORER, tasks, "poke_box", poke_plan(EXPLORER, EXPLORER_ARM, home, pitch),
                                         connect=(endpoint,), autostart=True, contacts=True))
        cell = write_cell(folder / "cell.yaml", robots, [box.container(), *objs])
        world = world_node(site, cell, listen=endpoint, wait_for=tuple(c["node"] for c in controls), seed=seed,
                           ground_truth_hz=4.0)
        started, watch = start_nodes(folder, [world, *controls], site, endpoint)
        cmap = _Map(watch, watch.ks)

        def start_taker() -> None:  # as an operator would: RUN to its task module
            replies = watch.t.query(watch.ks.control(TAKER, controls[0]["node"], "task"),
                                    encode(ControlRequest(cmd=Command.RUN, issuer="bench")))
            reply = decode(replies[0][1], ControlReply) if replies else None
            if reply is None or not reply.ok:
                raise RuntimeError(f"the taker's task did not start: {reply.error if reply else 'no reply'}")

        try:
            out = _supervise(watch, cmap, controls, names, mapped, max_attempts, max_time, start_taker)
        finally:
            cmap.sub.close()
            stop_nodes(started, watch)
    return {"variant": variant, "seed": seed, "objects": n_objects, **out}


def _supervise(watch, cmap: _Map, controls: list[dict], names: list[str], mapped: bool, max_attempts: int,  # type: ignore[no-untyped-def]
               max_time: float, start_taker) -> dict:
    """Watch a run to its end (the empty-box bench's supervisor): the explorer's task first when there is one, then
    the taker's, started then; returns what the run gave."""
    taker_task = f"{controls[0]['node']}/task"
    explored = 0.0
    if mapped:
        explorer_task = f"{controls[1]['node']}/task"
        while (done := watch.outcome(explorer_task)) is None:
            time.sleep(0.2)
            poses = watch.object_poses()
            if poses and poses[-1].hdr.t_sim >= max_time:
                break
        explored = done.hdr.t_sim if done is not None else max_time
        start_taker()
    start: float | None = None if not mapped else explored
    emptied: float | None = None
    why = ""
    while not why:
        time.sleep(0.2)
        poses = watch.object_poses()
        progress = watch.task_progress()  # the explorer's task has no grasp nor choose nodes
        if start is None and progress:
            start = progress[0].hdr.t_sim
        if emptied is None:
            emptied = next((m.hdr.t_sim for m in poses if box.in_box_poses(names, m) == 0), None)
        now = poses[-1].hdr.t_sim if poses else 0.0
        until = min(emptied if emptied is not None else np.inf, (start or 0.0) + max_time)
        attempts = sum(m.hdr.t_sim <= until for m in progress if box.attempt_started(m))
        if (ended := watch.outcome(taker_task)) is not None:
            why = f"the task ended: {ended.event} {ended.detail}"
        elif emptied is not None and now - emptied > 8.0:
            why = "supervisor: the box is empty"
        elif attempts > max_attempts:
            why = "supervisor: attempt limit"
        elif start is not None and now - start >= max_time:
            why = f"supervisor: {max_time:g} s of simulated time"
    start = start or 0.0
    # the map the taker took from: at its first choice (alone: after its own exploration)
    chose = next((m.hdr.t_sim for m in progress if m.kind == "entered" and m.node == "choose"), None)
    at = chose if chose is not None else now
    truth_msg = min(poses, key=lambda m: abs(m.hdr.t_sim - at))
    truth = {n: p[:3, 3] for n, p in zip(truth_msg.names, truth_msg.poses.numpy(), strict=True) if n in names}
    left = box.in_box_poses(names, poses[-1]) if emptied is None else 0
    end = emptied if emptied is not None else min(now, start + max_time)
    pokes = [e for e in watch.messages() if e.module.endswith("/poke") and e.event in watch.FINAL]
    attempts = min(attempts, max_attempts + 1)
    return {"attempts": attempts, "outcomes": box.attempt_outcomes(progress, attempts),
            "failed_approaches": sum(map(box.failed_approach, progress)), "time": end - start,
            "explored": explored, "left": left,
            "touches": [int(e.values.get("touches", 0)) for e in pokes],
            "success": left == 0, "result": why, "map": localisation(cmap.at(at), truth),
            "map_estimates": [list(e) for e in cmap.at(at)], "truth": {n: [float(v) for v in p] for n, p in truth.items()}}


def run(out_dir: pathlib.Path, quick: bool = False, runs: int | None = None, jobs: int = 1,
        max_time: float | None = None, max_attempts: int | None = None, first_seed: int = 100,
        objects: int | None = None) -> dict:
    """Both variants ``runs`` times each (seeds ``first_seed``, +1, ...; the same contents per seed in both) with
    ``objects`` in the box (default 5, the thesis's), on ``jobs`` processes; caps per run on the taker's simulated s
    and grasp attempts. ``quick``: one run of each with one object, poked at QUICK_PITCH."""
    from rich.console import Console
    from rich.table import Table

    from contactflow.nodes.params import ParamError

    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    n_runs = runs if runs is not None else (1 if quick else 10)
    n_objects = objects if objects is not None else (1 if quick else 5)
    if not 1 <= n_objects <= len(box.CELLS):
        raise ParamError(f"bench shared-contacts: --objects {n_objects} is not 1 to {len(box.CELLS)}")
    max_time = max_time if max_time is not None else (300.0 if quick else MAX_TIME)
    max_attempts = max_attempts if max_attempts is not None else (4 if quick else MAX_ATTEMPTS)
    pitch = QUICK_PITCH if quick else PITCH
    plan = [(v, first_seed + k, n_objects, max_attempts, max_time, pitch) for k in range(n_runs) for v in VARIANTS]
    t0 = time.perf_counter()
    results = run_logged(run_once, plan, jobs, out_dir / "shared_contacts_runs.jsonl", "shared contacts",
                         lambda r: f"{r['variant']} seed {r['seed']}: {r['left']} left")
    rows = [_row(v, [r for r in results if r["variant"] == v]) for v in VARIANTS]
    summary = {"benchmark": "shared_contacts", "explorer": EXPLORER, "taker": TAKER, "objects": n_objects,
               "runs_per_variant": n_runs, "first_seed": first_seed, "quick": quick, "max_time": max_time,
               "max_attempts": max_attempts, "poke_pitch": pitch, "localised_within": LOCALISED, "rows": rows,
               "wall_time": time.perf_counter() - t0, "runs": results}
    (out_dir / "shared_contacts.json").write_text(json.dumps(summary, indent=1))
    caps = (f"{n_objects} object{'s' if n_objects > 1 else ''} per box, {n_runs} seeded runs per variant; a run ends "
            f"after {max_time:g} s of the taker's simulated time or {max_attempts} attempts")
    table = Table(title=f"{TAKER} empties a box alone, or with the cell's map of {EXPLORER}'s touches", caption=caps)
    for col in ("variant", "attempts [95 %]", "how attempts ended, per box", f"{TAKER} time (s) [95 %]", f"{EXPLORER} exploring (s)", "boxes emptied [95 %]",
                f"objects localised (<= {100 * LOCALISED:g} cm)", "map error (cm)", "spurious estimates"):
        table.add_column(col)
    for r in rows:
        table.add_row(r["variant"], mean_text(r["attempts"], r["attempts_ci95"]), box.outcome_text(r["outcomes"]),
                      mean_text(r["time"], r["time_ci95"], 0), f"{r['explored']:.0f}" if r["explored"] else "-",
                      rate_text(r["emptied"]["successes"], r["runs"]), f"{r['localised']}/{r['objects']}",
                      f"{100 * r['error']:.1f}" if r["error"] is not None else "-", f"{r['spurious']}")
    Console().print(table)
    _plot(results, out_dir / "shared_contacts.png")
    return summary


def _row(variant: str, rs: list[dict]) -> dict:
    errors = [d for r in rs for d in r["map"]["nearest"].values() if d is not None and d <= LOCALISED]
    attempts, times = mean([r["attempts"] for r in rs]), mean([r["time"] for r in rs])
    return {"variant": variant, "runs": len(rs), "attempts": attempts["mean"], "attempts_ci95": attempts["ci95"],
            "outcomes": box.mean_outcomes(rs), "time": times["mean"], "time_ci95": times["ci95"],
            "explored": float(np.mean([r["explored"] for r in rs])),
            "emptied": rate(sum(r["success"] for r in rs), len(rs)),
            "localised": sum(r["map"]["localised"] for r in rs), "objects": sum(r["map"]["objects"] for r in rs),
            "error": float(np.mean(errors)) if errors else None, "spurious": sum(r["map"]["spurious"] for r in rs)}


def _plot(results: list[dict], path: pathlib.Path) -> None:
    """Top view per seed: the box, the objects where the taker began (circles), each variant's map (crosses)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    seeds = sorted({r["seed"] for r in results})
    cols = min(5, len(seeds))
    rows = -(-len(seeds) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(2.6 * cols, 2.8 * rows), squeeze=False)
    (cx, cy), (ix, iy) = box.BOX_CENTER, box.INNER
    style = {"alone": ("tab:blue", "+", f"{TAKER}'s own map"), "with_map": ("tab:red", "x", f"{EXPLORER}'s map")}
    for ax, seed in zip(axes.flat, seeds, strict=False):
        ax.add_patch(Rectangle((cx - ix / 2, cy - iy / 2), ix, iy, fill=False, color="0.4"))
        for r in (r for r in results if r["seed"] == seed):
            color, marker, label = style[r["variant"]]
            for p in r["truth"].values():
                ax.add_patch(Circle(p[:2], 0.02, fill=False, color=color, alpha=0.5))
            est = np.array([e[1:3] for e in r["map_estimates"]]).reshape(-1, 2)
            ax.scatter(est[:, 0], est[:, 1], marker=marker, color=color, label=label)
        ax.set_title(f"seed {seed}", fontsize=9)
        ax.set_xlim(cx - ix / 2 - 0.02, cx + ix / 2 + 0.02)
        ax.set_ylim(cy - iy / 2 - 0.02, cy + iy / 2 + 0.02)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
    for ax in axes.flat[len(seeds):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=6, loc="upper left")
    fig.suptitle("objects (circles, where the taker began) and the map it took them from", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
