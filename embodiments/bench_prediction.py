"""``contactflow bench prediction``: the robot's predictor against a world that differs from what the robot believes (thesis ch. 5).

Every run is the runtime's reference cell (a world node, tombatossals' control node with its
contact fusion and its predictor, in lockstep over zenoh): pick the can and place it, once with
corrections off (``pick_and_place`` of ``thesis.yaml``) and once on (``careful_pick_and_place``:
a surprise during the carry stops it, the hand withdraws and carries on; a lost can is looked
for and picked again). The predictor believes the cell file (a 0.2 kg can at its place); the
world differs:

- ``undisturbed``: only the reality gap, drawn per seed: the can up to 1 cm from its believed
  place, its mass and friction 0.8-1.25 times the believed (thesis Fig. 5.16 protocol);
- ``heavy``: the gap, and a can four times heavier than believed;
- ``obstacle``: the gap, and an unseen crate beside the can, in the hand's way;
- ``slip``: the gap, and the can pulled out of the hand mid-carry (40 N down from 14 s for 0.6 s:
  an agent the robot knows nothing of, the world's ``pushes``).

Measured per case over ``runs`` seeded runs: how often the predictor reported a mismatch
(detection rate on the surprises, false alarms on the undisturbed runs), the latency from the
physical event (the hand's first touch of the crate, or of the heavy can, from ``eval/``; the
pull's start for the slip) to the first mismatch, the predicted arm joints' and can's error
against the world over time (Fig. 5.16: thesis < 0.1 rad, < 2.5 cm), and the predictor's
real-time factor on its own compute, how many mismatches a run heard (a load the predictor learned
as a held object's mass is told once, not every second) and the task's success with corrections
off and on, side by side (95 % Wilson intervals). Writes ``prediction.json``, ``prediction.md`` and
``prediction.png``.
"""

from __future__ import annotations

import json
import pathlib
import threading
import time

import numpy as np

from contactflow.embodiments.layout import CELLS
from contactflow.nodes.stats import rate_text, wilson

CASES = ("undisturbed", "heavy", "obstacle", "slip")
BELIEF = CELLS / "pick_place.yaml"  # what the robot believes
ROBOT = "tombatossals"
CAN = "cyl"
CRATE = "crate"
PULL = (14.0, 14.6, 40.0)  # s, s, N: the slip's pull on the can, straight down, mid-carry
CRATE_LINE = "  - {name: crate, kind: box, size: [0.06, 0.06, 0.1], xyz: [0.55, -0.2, 0.80], mass: 1.0, friction: 0.8}\n"
OBJECT_GOAL = 0.025  # m, thesis Fig. 5.16: the predicted object within 2.5 cm of the real one
AFTER = 2.0  # s of wall time a run goes on after its task ended: a surprise that ended the task is still told


class PredictorWatch:
    """A tool session on a robot's predictor (``predict/<robot>/...``) and its true contacts (``eval/``)."""

    def __init__(self, site: str, endpoint: str, robot: str = ROBOT) -> None:
        from contactflow.nodes.keys import KeySpace

        self.ks, self.endpoint, self.robot = KeySpace(site), endpoint, robot
        self.states: list = []
        self.mismatches: list = []
        self.touches: dict[str, float] = {}  # object -> simulated time the robot first touched it
        self._lock = threading.Lock()
        self.t = None

    def open(self) -> None:
        from contactflow.embodiments.messages import (
            PredictedState,
            PredictionMismatch,
            TrueContacts,
        )
        from contactflow.nodes.transport import ZenohSettings, ZenohTransport
        from contactflow.nodes.wire import decode

        self.t = ZenohTransport(ZenohSettings(connect=(self.endpoint,))).open()
        on = {self.ks.predict(self.robot, "state"): lambda k, p: self._add(self.states, decode(p, PredictedState, k)),
              self.ks.predict(self.robot, "mismatch"):
                  lambda k, p: self._add(self.mismatches, decode(p, PredictionMismatch, k)),
              self.ks.evaluation(self.robot, "true_contacts"): lambda k, p: self._touch(decode(p, TrueContacts, k))}
        for key, fn in on.items():
            self.t.subscribe(key, fn)

    def _add(self, where: list, msg) -> None:
        with self._lock:
            where.append(msg)

    def _touch(self, msg) -> None:
        with self._lock:
            for other in set(msg.body_b):
                self.touches.setdefault(other, msg.hdr.t_sim)

    def close(self) -> None:
        if self.t is not None:
            self.t.close()


def world_scene(case: str, seed: int) -> str:
    """The world's cell file of a run: the belief with the reality gap of ``seed`` and the surprise of ``case``."""
    if case not in CASES:
        raise ValueError(f"bench prediction: case {case!r} is not one of {CASES}")
    rng = np.random.default_rng(seed)
    r, a = 0.01 * np.sqrt(rng.uniform()), rng.uniform(0.0, 2 * np.pi)
    mass = 0.2 * rng.uniform(0.8, 1.25) * (4.0 if case == "heavy" else 1.0)
    friction = 0.8 * rng.uniform(0.8, 1.25)
    x, y = 0.55 + r * np.cos(a), -0.3 + r * np.sin(a)
    believed = "xyz: [0.55, -0.3, 0.81], mass: 0.2, friction: 0.8"
    text = BELIEF.read_text()
    if believed not in text:
        raise ValueError(f"bench prediction: the can's line of {BELIEF} changed; the world of a run is made from it")
    text = text.replace(believed, f"xyz: [{x:.4f}, {y:.4f}, 0.81], mass: {mass:.3f}, friction: {friction:.3f}")
    return text + (CRATE_LINE if case == "obstacle" else "")


def _run(case: str, seed: int, folder: str, corrections: bool = False) -> dict:
    from contactflow.embodiments.layout import run_cell, table_cell, world_node
    from contactflow.nodes.procs import free_port

    folder_ = pathlib.Path(folder)
    folder_.mkdir(parents=True, exist_ok=True)
    scene = folder_ / "world_cell.yaml"
    scene.write_text(world_scene(case, seed))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    site = f"pred{free_port()}"
    _, (control,) = table_cell(site, endpoint, predictor={"belief": str(BELIEF)},
                               task="careful_pick_and_place" if corrections else "pick_and_place")
    pushes = (f"{CAN}@{PULL[0]}-{PULL[1]}:0,0,{-PULL[2]}",) if case == "slip" else ()
    world = world_node(site, scene, listen=endpoint, wait_for=(control["node"],), ground_truth_hz=20.0,
                       contacts_hz=50.0, seed=seed, pushes=pushes)
    watch = PredictorWatch(site, endpoint)
    try:  # the watch joins once the world listens, before the control node: it hears the predictor from the start
        cell = run_cell(folder_, world, [control], endpoint, timeout=300.0, after=AFTER, joined=watch.open)
    finally:
        watch.close()
    return {**measure(case, seed, cell, watch), "corrections": corrections}


def measure(case: str, seed: int, cell, watch: PredictorWatch) -> dict:
    """One run's numbers: outcome, mismatches, the physical event and the latency, the error curves."""
    outcome = cell.outcomes[ROBOT]
    if case == "slip":
        event = PULL[0]
    elif case == "heavy":
        # the heavier can differs from the first touch on: pushed by the grasping hand it resists as its mass
        # says, and its weight pulls once lifted (the first mismatch came 2 s before the lift: latency -2 s)
        event = watch.touches.get(CAN)
    else:
        event = watch.touches.get(CRATE)
    mismatches = [{"t": m.t, "since": m.since, "kind": str(m.kind), "part": m.part, "value": m.value,
                   "update": m.update} for m in watch.mismatches]
    first = min((m["t"] for m in mismatches), default=None)
    truth = sorted(cell.poses, key=lambda m: m.hdr.t_sim)
    times, joint, obj = [], [], []
    k = 0
    for s in sorted(watch.states, key=lambda s: s.t):
        while k + 1 < len(truth) and truth[k + 1].hdr.t_sim <= s.t + 1e-6:
            k += 1
        if not truth or truth[k].hdr.t_sim > s.t + 1e-6 or CAN not in s.objects:
            continue
        gt = truth[k]
        times.append(s.t)
        joint.append(s.joint_error)
        predicted = s.poses.numpy()[s.objects.index(CAN)][:3, 3]
        obj.append(float(np.linalg.norm(predicted - gt.poses.numpy()[gt.names.index(CAN)][:3, 3])))
    states = sorted(watch.states, key=lambda s: s.t)
    rtf = ((states[-1].t - states[0].t) / (states[-1].compute - states[0].compute)
           if len(states) > 1 and states[-1].compute > states[0].compute else 0.0)
    return {"case": case, "seed": seed, "outcome": str(outcome.event), "sim_s": cell.sim_s, "wall_s": cell.wall_s,
            "event_t": event, "first_mismatch_t": first,
            "latency": None if first is None or event is None else first - event,
            "mismatches": mismatches, "times": times, "joint_error": joint, "object_error": obj,
            "predictor_rtf": rtf}


def summarize(runs: list[dict]) -> list[dict]:
    """One row per case and corrections off / on."""
    rows = []
    for case, corrections in ((c, on) for c in CASES for on in (False, True)):
        mine = [r for r in runs if r["case"] == case and r.get("corrections", False) == corrections]
        if not mine:
            continue
        flagged = [r for r in mine if r["mismatches"]]
        lat = [r["latency"] for r in mine if r["latency"] is not None]
        kinds: dict[str, int] = {}
        for r in flagged:
            first = min(r["mismatches"], key=lambda m: m["t"])
            kinds[first["kind"]] = kinds.get(first["kind"], 0) + 1
        rows.append({
            "case": case, "corrections": corrections, "runs": len(mine),
            "mismatches_median": float(np.median([len(r["mismatches"]) for r in mine])),
            "learned": sum(any(m.get("update") for m in r["mismatches"]) for r in mine), "flagged": len(flagged), "rate": len(flagged) / len(mine),
            "first_kinds": kinds, "latency_median": float(np.median(lat)) if lat else None,
            "latency_max": float(np.max(lat)) if lat else None,
            "joint_error_max": max((max(r["joint_error"], default=0.0) for r in mine), default=0.0),
            "object_error_max": max((max(r["object_error"], default=0.0) for r in mine), default=0.0),
            "object_error_median_of_max": float(np.median([max(r["object_error"], default=0.0) for r in mine])),
            "object_within": sum(max(r["object_error"], default=0.0) < OBJECT_GOAL for r in mine),
            "task_success": sum(r["outcome"] == "success" for r in mine),
            "task_success_ci95": list(wilson(sum(r["outcome"] == "success" for r in mine), len(mine))),
            "predictor_rtf": float(np.median([r["predictor_rtf"] for r in mine])),
        })
    return rows


def run(out_dir: pathlib.Path, quick: bool = False, runs: int | None = None, jobs: int = 1) -> dict:
    """``runs`` seeded runs (default 20; quick: 1) of every case, corrections off and on (the same seeds), on
    ``jobs`` worker processes."""
    from rich.console import Console
    from rich.progress import Progress as Bar
    from rich.table import Table

    from contactflow.embodiments.parallel import run_all

    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    n = runs or (1 if quick else 20)
    plan = [(case, 1000 + k, str(out_dir / "runs" / f"{case}_{'on' if on else 'off'}_{k}"), on)
            for case in CASES for on in (False, True) for k in range(n)]
    t0 = time.perf_counter()
    with Bar(transient=True) as bar:
        job = bar.add_task(f"prediction ({len(plan)} runs)", total=len(plan))
        results = run_all(_run, plan, jobs, lambda _, r: bar.update(
            job, advance=1, description=f"{r['case']} seed {r['seed']}: {len(r['mismatches'])} mismatch(es)"),
            fresh=True)
    rows = summarize(results)
    summary = {"benchmark": "prediction", "robot": ROBOT, "runs_per_case": n, "rows": rows,
               "goals": {"detection_rate": 0.9, "false_alarm_rate": 0.05, "latency_s": 0.2, "joint_error_rad": 0.1,
                         "object_error_m": OBJECT_GOAL, "predictor_rtf": 10.0},
               "wall_time": time.perf_counter() - t0, "runs": results}
    (out_dir / "prediction.json").write_text(json.dumps(summary, indent=1))
    md = ["| case | corrections | runs | with a mismatch | first mismatch kinds | mismatches per run (median) | "
          "mass learned | latency median / max (s) | joint error max (rad) | can within 2.5 cm all along | "
          "can error, median of run maxima (cm) | task success | predictor RTF (own compute) |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    table = Table(title=f"The predictor against the world ({ROBOT}'s pick and place, {n} seeded runs per case)")
    for col in ("case", "corr.", "runs", "with a mismatch", "first kinds", "per run", "mass learned",
                "latency med/max (s)", "joint err (rad)", "can < 2.5 cm", "can err (cm)", "task success", "predictor RTF"):
        table.add_column(col)
    for r in rows:
        lat = "-" if r["latency_median"] is None else f"{r['latency_median']:.2f} / {r['latency_max']:.2f}"
        kinds = ", ".join(f"{k} {v}" for k, v in sorted(r["first_kinds"].items())) or "-"
        cells = [r["case"], "on" if r["corrections"] else "off", str(r["runs"]),
                 f"{r['flagged']} ({100 * r['rate']:.0f} %)", kinds, f"{r['mismatches_median']:g}",
                 f"{r['learned']}/{r['runs']}", lat, f"{r['joint_error_max']:.3f}", f"{r['object_within']}/{r['runs']}",
                 f"{100 * r['object_error_median_of_max']:.1f}", rate_text(r["task_success"], r["runs"]),
                 f"{r['predictor_rtf']:.1f}"]
        table.add_row(*cells)
        md.append("| " + " | ".join(cells) + " |")
    md.append("\nGoals (issue #27): detection >= 90 % on each surprise, false alarms <= 5 % on undisturbed runs, "
              "latency <= 0.2 s, Fig. 5.16 errors < 0.1 rad and < 2.5 cm, predictor >= 10x real time on one core; "
              "task success with corrections off and on, side by side.")
    (out_dir / "prediction.md").write_text("\n".join(md) + "\n")
    Console().print(table)
    _plot(results, out_dir / "prediction.png")
    return summary


def _plot(runs: list[dict], path: pathlib.Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 3.8))
    colors = dict(zip(CASES, ("#2ca02c", "#d62728", "#9467bd", "#ff7f0e"), strict=True))
    for r in runs:
        if not r["times"]:
            continue
        c, ls = colors[r["case"]], "--" if r.get("corrections") else "-"
        axes[0].plot(r["times"], r["joint_error"], color=c, ls=ls, lw=0.7, alpha=0.6)
        axes[1].plot(r["times"], np.maximum(100 * np.asarray(r["object_error"]), 0.01), color=c, ls=ls, lw=0.7,
                     alpha=0.6)
        for m in r["mismatches"]:
            axes[2].scatter(m["t"], CASES.index(r["case"]) + 0.3 * (hash(m["kind"]) % 3 - 1) / 3, color=c, s=8)
        if r["event_t"] is not None:
            axes[2].scatter(r["event_t"], CASES.index(r["case"]), marker="|", color="k", s=60)
    axes[0].axhline(0.1, color="k", ls="--", lw=0.8)
    axes[0].set(title="predicted vs measured arm joints", xlabel="t (s)", ylabel="max error (rad)")
    axes[1].axhline(100 * OBJECT_GOAL, color="k", ls="--", lw=0.8)
    axes[1].set_yscale("log")
    axes[1].set(title="predicted vs true can position", xlabel="t (s)", ylabel="error (cm, log)")
    axes[2].set(title="mismatches (dots) and physical events (|)", xlabel="t (s)", yticks=range(len(CASES)),
                yticklabels=CASES)
    handles = [plt.Line2D([], [], color=colors[c], label=c) for c in CASES] + [
        plt.Line2D([], [], color="k", ls="--", label="corrections on")]
    axes[0].legend(handles=handles, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
