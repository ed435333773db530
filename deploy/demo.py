"""``contactflow demo``: the thesis §7.3 experiment on three robots over zenoh, with a report.

It starts, as local processes on loopback, eight nodes: per robot (Tombatossals, Melfa,
Baxter) a world node simulating the robot's cell (the §7.3 table, a box in front of a
target) and a control node in lockstep with it (the robot's agent, its primitive modules,
contact fusion; Tombatossals' also hosts the broker), plus Tombatossals' 2D and 3D vision
nodes fed by its world's Kinect stream, and Tombatossals' predictor (thesis ch. 5) on its control
node. The demo then dispatches ATD 1 (push the box away)
and ATD 2 (pick the target behind it) with ``--on all``: each agent runs its translation
on the task engine, which runs the node's primitive modules, which drive the world's robot
over the key space. It shows the abstract progress, the fused contact events and the
prediction mismatches live and writes a report folder: ``summary.json``, ``timeline.png``,
``contacts.png`` and the camera frames the vision nodes received. An ATD's
``prediction_mismatch`` transitions (corrections, thesis §5.7) taken are reported per task.

Each world publishes its object poses on the evaluation keys (ground truth); the demo
checks with them what each task physically did (the pushed box moved towards its target,
the placed object ended near its place location). The exit code is non-zero unless every
task was dispatched to every robot, ended in success on each, and passed those checks.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rich.console import Console
from rich.progress import Progress

from contactflow.abstraction.agent import EXAMPLES
from contactflow.abstraction.atd import Atd, parse_atd
from contactflow.abstraction.cli import progress_table
from contactflow.abstraction.client import TaskFollow, close, dispatch
from contactflow.abstraction.events import AbstractEvent
from contactflow.abstraction.frames import TaskFrame, to_world
from contactflow.abstraction.messages import AbstractProgressMsg
from contactflow.abstraction.primitives import AbstractPrimitive
from contactflow.abstraction.profiles import PROFILES
from contactflow.deploy.launcher import render, tool_endpoints
from contactflow.deploy.manifest import DEFAULT_MANIFEST, Manifest, load_manifest
from contactflow.deploy.recorder import Recorder
from contactflow.embodiments.messages import DepthImage, ObjectPoses, PredictionMismatch
from contactflow.fusion.messages import ContactEventMsg
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.procs import free_port_block, spawn_node, stop_process, wait_for
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import M, WireError, decode

ATDS = ("push_away.xml", "pick_place_behind.xml")
ROBOTS = ("tombatossals", "melfa", "baxter")
REC = "contactflow.recognition"
QUICK_CAMERA_HZ = 0.25  # Hz of simulated time: --quick feeds the vision nodes fewer depth frames
PUSH_PROGRESS = 0.02  # m, how much closer to its target (top view) a pushed object must end
PLACE_TOLERANCE = 0.06  # m, how far (top view) from its place location a placed object may end (about its diameter)
PLACE_HEIGHT = 0.02  # m, how far its centre may end above or below the place location (fallen over: further)
QUIET_LIMIT = 150.0  # s of wall time a dispatched task may go without progress before the demo stops waiting for it
TASK_LIMIT = 1200.0  # s of wall time the demo waits for one task at most (a slow machine is slow, not stalled)
Positions = Mapping[str, Sequence[float]]  # object name -> world position (m)


def nominal(atd: Atd) -> set[str]:
    """The states a run reaches when nothing surprises it: from the start, over the transitions that need no
    prediction mismatch (a correction's branch, where an object may be set back where it was, is not one)."""
    seen, todo = {atd.start}, [atd.start]
    while todo:
        here = todo.pop()
        for t in atd.transitions:
            if (t.origin == here and t.destination not in seen
                    and all(e.event is not AbstractEvent.PREDICTION_MISMATCH for e in t.events)):
                seen.add(t.destination)
                todo.append(t.destination)
    return seen


def physical_checks(atd: Atd, frame: TaskFrame, before: Positions, after: Positions) -> list[dict]:
    """What the ATD's push and place states (of its nominal run) should have done to their objects, checked on
    ground truth."""
    world = to_world(atd, frame)
    out = []
    planned = nominal(atd)
    for state in world.states:
        if (state.type not in (AbstractPrimitive.PUSH, AbstractPrimitive.PLACE) or state.goal is None
                or state.name not in planned):
            continue
        obj = world.object_of(state)
        if obj is None:
            continue
        check: dict = {"state": state.name, "kind": str(state.type), "object": obj.name,
                       "goal": [round(v, 4) for v in state.goal]}
        if obj.name not in before or obj.name not in after:
            out.append({**check, "ok": False, "why": f"no ground truth for {obj.name!r}"})
            continue
        d0, d1 = (math.dist(p[:2], state.goal[:2]) for p in (before[obj.name], after[obj.name]))
        check.update(start=[round(float(v), 4) for v in before[obj.name]],
                     end=[round(float(v), 4) for v in after[obj.name]],
                     distance_before=round(d0, 4), distance_after=round(d1, 4))
        if state.type is AbstractPrimitive.PUSH:
            ok = d1 <= d0 - PUSH_PROGRESS
            why = f"moved {d0 - d1:.3f} m towards its target (needs {PUSH_PROGRESS} m)"
        else:
            dz = float(after[obj.name][2]) - state.goal[2]
            ok = d1 <= PLACE_TOLERANCE and abs(dz) <= PLACE_HEIGHT
            why = (f"ended {d1:.3f} m from its place location (tolerance {PLACE_TOLERANCE} m), "
                   f"{dz:+.3f} m in height (tolerance {PLACE_HEIGHT} m)")
        out.append({**check, "ok": ok, "why": why})
    return out


def deployment(site: str, folder: Path, camera_hz: float = 1.0, idle: str = "pause") -> Manifest:
    """The default manifest (``deploy/manifests/default.yaml``) on this machine: its own site and
    loopback ports, Tombatossals' Kinect stream at ``camera_hz``, the worlds' ``idle`` behaviour
    (``pause``, as shipped: a world stands still while its robot has no task)."""
    port = free_port_block(32)  # the nodes listen on consecutive ports from it
    text = (DEFAULT_MANIFEST.read_text().replace("site: lab", f"site: {site}").replace("cf/lab/", f"cf/{site}/")
            .replace("port: 7450", f"port: {port}").replace("camera_hz: 1.0", f"camera_hz: {camera_hz}")
            .replace("idle: pause", f"idle: {idle}"))
    path = folder / "manifest.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return load_manifest(path)


@dataclass
class Record:
    t0: float = field(default_factory=time.time)
    progress: list[dict] = field(default_factory=list)
    contacts: list[dict] = field(default_factory=list)
    objects: list[int] = field(default_factory=list)
    frames: list[DepthImage] = field(default_factory=list)
    truth: dict[str, list[dict[str, list[float]]]] = field(default_factory=dict)  # robot -> object positions
    mismatches: list[dict] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)


def _plots(out: Path, rec: Record, tasks: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(11, 4.5))
    rows = {r: i for i, r in enumerate(ROBOTS)}
    colours = {"success": "tab:green", "hardware_failure": "tab:red", "failure": "tab:orange", "error": "tab:red",
               "timeout": "tab:purple"}
    for r in ROBOTS:
        entered = [p for p in rec.progress if p["robot"] == r and p["kind"] in ("entered", "finished")]
        for a, b in zip(entered, entered[1:], strict=False):
            if a["kind"] == "entered":
                ax.barh(rows[r], b["t"] - a["t"], left=a["t"], height=0.5, color="tab:blue", alpha=0.35,
                        edgecolor="k")
                ax.text(a["t"], rows[r] + 0.3, a["state"], fontsize=6, rotation=30)
        for p in rec.progress:
            if p["robot"] == r and p["final"]:
                ax.plot(p["t"], rows[r], "s", color=colours.get(p["outcome"], "k"), ms=9)
    for mm in rec.mismatches:
        if mm["robot"] in rows:
            ax.plot(mm["t"], rows[mm["robot"]] + 0.3, "X", color="tab:red", ms=8)
            ax.text(mm["t"], rows[mm["robot"]] + 0.38, f"mismatch: {mm['kind']}", fontsize=6, color="tab:red")
    for c in rec.contacts:
        if c["robot"] in rows:
            ax.plot(c["t"], rows[c["robot"]] - 0.3, "v" if c["event"] == "contact_made" else "^",
                    color="tab:red" if c["event"] == "contact_made" else "tab:gray", ms=5)
    for t in tasks:
        ax.axvline(t["t_dispatch"], color="k", ls="--", lw=0.8)
        ax.text(t["t_dispatch"], len(ROBOTS) - 0.4, t["atd"], fontsize=8)
    ax.set_yticks(list(rows.values()), list(rows))
    ax.set_xlabel("s since the demo started")
    ax.set_title("Abstract states per robot (bars), outcomes (squares), contact made/broken (triangles), "
                 "prediction mismatches (X)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "timeline.png", dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 6))
    for r, marker in zip(ROBOTS, "os^", strict=True):
        pts = [c["location"] for c in rec.contacts if c["robot"] == r and c["event"] == "contact_made"]
        if pts:
            ax.scatter([p[0] for p in pts], [p[1] for p in pts], marker=marker, label=f"{r} ({len(pts)})")
    for name, xy, size in (("box (start)", (0.50, 0.0), 0.05), ("target", (0.62, 0.0), 0.05)):
        ax.add_patch(plt.Rectangle((xy[0] - size / 2, xy[1] - size / 2), size, size, fill=False, ls="--"))
        ax.text(xy[0], xy[1] + 0.04, name, fontsize=8, ha="center")
    ax.set_xlabel("world x (m)")
    ax.set_ylabel("world y (m)")
    ax.set_aspect("equal")
    ax.set_title("Fused contacts made (top view)")
    if rec.contacts:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "contacts.png", dpi=120)
    plt.close(fig)

    frames = out / "frames"
    frames.mkdir(exist_ok=True)
    for i, f in enumerate(rec.frames[-3:]):
        fig, ax = plt.subplots(figsize=(6.4, 4.8))
        im = ax.imshow(f.depth.numpy(), cmap="viridis")
        fig.colorbar(im, ax=ax, label="depth (m)")
        ax.set_title(f"tombatossals {f.camera} depth, {f.hdr.t_wall - rec.t0:.1f} s into the demo")
        fig.savefig(frames / f"kinect_{i}.png", dpi=100)
        plt.close(fig)


def _decoded(type_: type[M], fn: Callable[[str, M], None]) -> Callable[[str, bytes], None]:
    """A subscriber that hands ``fn`` each payload decoded as ``type_``; one that is not one is skipped."""
    def on(key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, type_, key)
        except WireError:
            return
        fn(key, msg)
    return on


def run(out: Path, quick: bool = False, console: Console | None = None, site: str | None = None,
        connect: tuple[str, ...] = (), listen: tuple[str, ...] = (), record: bool = False) -> int:
    """Run the demo into ``out``; 0 only when both ATDs succeeded on every robot as checked on ground truth.

    ``quick`` runs the same experiment with the stations' cameras at a lower rate (less vision work).
    ``site`` names the key space (default: a fresh ``demoNNNNN``); every node and the demo's own
    session also connect to ``connect`` (join an existing zenoh network); the demo's session
    listens on ``listen`` (default: loopback only), so outside clients can attach there.
    ``record``: the whole key space goes into ``out/demo.mcap`` (``contactflow record``).
    """
    from contactflow.recognition.messages import SegmentedObjects  # open3d: only once the demo runs

    console = console or Console()
    out = out.resolve()  # the generated node configurations name their zenoh files by absolute path
    out.mkdir(parents=True, exist_ok=True)
    site = site or f"demo{int(time.time()) % 100000}"
    ks = KeySpace(site)
    m = deployment(site, out / "config", camera_hz=QUICK_CAMERA_HZ if quick else 1.0)
    launches = render(m, out / "config", local=True, connect=connect)
    nodes = [ln.node.name for ln in launches]
    rec = Record()
    procs = {ln.node.name: spawn_node(ln.config, out / "logs" / f"{ln.node.name}.log") for ln in launches}
    tool = ZenohTransport(ZenohSettings(connect=(*tool_endpoints(m, local=True), *connect), listen=listen)).open()
    console.print(f"site [bold]{site}[/]; nodes listen on " + ", ".join(ln.endpoint for ln in launches)
                  + (f"; the demo listens on {', '.join(listen)}" if listen else "")
                  + (f" and connects to {', '.join(connect)}" if connect else ""))
    console.print(f"attach: contactflow ls --site {site} --connect {launches[0].endpoint}")

    def on_contact(key: str, c: ContactEventMsg) -> None:
        with rec.lock:
            rec.contacts.append({"t": round(time.time() - rec.t0, 3), "robot": c.robot, "link": c.link,
                                 "event": str(c.event), "location": [round(v, 4) for v in c.location],
                                 "sources": c.sources, "inputs": [f"{i.source}#{i.seq}" for i in c.hdr.inputs]})
        console.print(f"  [magenta]contact[/] {c.robot}/{c.link}: {c.event} at "
                      f"({', '.join(f'{v:.3f}' for v in c.location)})")

    def on_objects(key: str, msg: SegmentedObjects) -> None:
        with rec.lock:
            rec.objects.append(len(msg.objects))

    def on_depth(key: str, msg: DepthImage) -> None:
        with rec.lock:
            rec.frames = rec.frames[-2:] + [msg]

    def on_truth(key: str, msg: ObjectPoses) -> None:
        poses = msg.poses.numpy()
        if poses.shape != (len(msg.names), 4, 4):
            return
        robot = key.rsplit("/", 2)[-2]
        with rec.lock:
            rec.truth.setdefault(robot, []).append({n: [float(v) for v in poses[i, :3, 3]]
                                                    for i, n in enumerate(msg.names)})

    def on_mismatch(key: str, mm: PredictionMismatch) -> None:
        with rec.lock:
            rec.mismatches.append({"t": round(time.time() - rec.t0, 3), "t_sim": mm.t, "robot": mm.robot,
                                   "kind": str(mm.kind), "part": mm.part, "value": mm.value, "detail": mm.detail,
                                   "update": mm.update})
        console.print(f"  [bold red]prediction mismatch[/] {mm.robot} at t={mm.t:.2f} s: {mm.detail}"
                      + (f"; its model learns: {mm.update}" if mm.update else ""))

    def truth_count(robot: str) -> int:
        with rec.lock:
            return len(rec.truth.get(robot, []))

    def on_progress(m: AbstractProgressMsg) -> None:
        with rec.lock:
            rec.progress.append({"t": round(time.time() - rec.t0, 3), "t_sim": m.hdr.t_sim, "robot": m.robot, "kind": m.kind,
                                 "state": m.state, "transition": m.transition, "event": m.event,
                                 "concrete": m.concrete, "final": m.final, "outcome": m.outcome,
                                 "task": m.task_id, "detail": m.detail[:200]})

    subs = [tool.subscribe(ks.fused("*", "events"), _decoded(ContactEventMsg, on_contact)),
            tool.subscribe(ks.output("tombatossals", "*", "objects", "objects"), _decoded(SegmentedObjects, on_objects)),
            tool.subscribe(ks.robot("tombatossals", "depth"), _decoded(DepthImage, on_depth)),
            tool.subscribe(ks.evaluation("*", "object_poses"), _decoded(ObjectPoses, on_truth)),
            tool.subscribe(ks.predict("*", "mismatch"), _decoded(PredictionMismatch, on_mismatch))]
    recorder = Recorder(tool, [f"{ks.prefix}/**"], out / "demo.mcap", site).start() if record else None
    tasks: list[dict] = []
    code = 1
    try:
        with Progress(console=console, transient=True) as bar:
            task = bar.add_task(f"starting {len(nodes)} nodes", total=len(ROBOTS))

            def robots_up() -> bool:
                n = len(tool.alive(ks.alive_robot(), timeout=0.5))
                bar.update(task, completed=n)
                return n >= len(ROBOTS)

            up = wait_for(robots_up, timeout=90)
        nodes_up = tool.alive(ks.alive_node(), timeout=1.0)
        console.print(f"[green]{len(nodes_up)} nodes up[/] ({time.time() - rec.t0:.1f} s): "
                      + ", ".join(k.rsplit("/", 1)[-1] for k in sorted(nodes_up)))
        if not up:
            console.print("[red]not every robot came up; see the logs in[/] " + str(out / "logs"))
            return 1
        for name in ATDS:
            text = (EXAMPLES / name).read_text()
            console.rule(f"{name} --on all")
            t_dispatch = round(time.time() - rec.t0, 3)
            seen = {r: truth_count(r) for r in ROBOTS}
            follow: TaskFollow = dispatch(tool, ks, text, name, target="all", on_progress=on_progress)
            if follow.reply is None or not follow.reply.ok:
                console.print(f"[red]not dispatched:[/] {follow.reply.error if follow.reply else ''}")
                tasks.append({"atd": name, "t_dispatch": t_dispatch, "dispatched": False})
                continue
            console.print(f"dispatched to {', '.join(follow.reply.robots)}")
            from rich.live import Live

            with Live(progress_table(follow), console=console, refresh_per_second=4) as live:
                start = heard = time.monotonic()
                n_heard = len(follow.progress)
                while not follow.done.wait(0.25):
                    now = time.monotonic()
                    if len(follow.progress) != n_heard:
                        n_heard, heard = len(follow.progress), now
                    if now - heard > QUIET_LIMIT or now - start > TASK_LIMIT:
                        break
                    live.update(progress_table(follow))
                live.update(progress_table(follow))
            if not follow.done.is_set():
                console.print(f"[red]stopped waiting for {name}[/]: no progress for {time.monotonic() - heard:.0f} s "
                              f"({time.monotonic() - start:.0f} s since its dispatch)")

            def settled(follow: TaskFollow = follow, seen: dict[str, int] = seen) -> bool:
                # a robot's last report may arrive after the broker's, and its world (published just
                # before that report) after either
                finals = {m.robot for m in follow.progress if m.final and m.robot != "broker"}
                return finals >= set(follow.reply.robots) and all(truth_count(r) > seen[r] for r in finals)

            wait_for(settled, timeout=5)
            close(follow)
            outcomes = {m.robot: m.outcome for m in follow.progress if m.final and m.robot != "broker"}
            physical = {}
            atd = parse_atd(text, name)
            for r in sorted(outcomes):
                with rec.lock:
                    snaps = list(rec.truth.get(r, []))
                before = snaps[seen[r] - 1] if seen[r] > 0 else (snaps[0] if snaps else {})
                physical[r] = physical_checks(atd, PROFILES[r].task_frame, before, snaps[-1] if snaps else {})
            ok = (follow.final is not None and sorted(follow.reply.robots) == sorted(ROBOTS)
                  and all(outcomes.get(r) == "success" for r in ROBOTS)
                  and all(c["ok"] for checks in physical.values() for c in checks))
            corrections = [{"robot": m.robot, "transition": m.transition, "t_sim": m.hdr.t_sim, "detail": m.detail}
                           for m in follow.progress
                           if m.kind == "edge" and m.event == AbstractEvent.PREDICTION_MISMATCH.value]
            # a robot that did not succeed: the last thing it said of its task (a fault names the joint)
            why = {r: next((m.detail for m in reversed(follow.progress) if m.robot == r and m.detail), "")
                   for r, o in outcomes.items() if o != "success"}
            tasks.append({"atd": name, "t_dispatch": t_dispatch, "dispatched": True, "robots": follow.reply.robots,
                          "outcomes": outcomes, "why": why, "finished": follow.final is not None, "physical": physical,
                          "corrections": corrections, "ok": ok})
        code = 0 if len(tasks) == len(ATDS) and all(t.get("ok") for t in tasks) else 1
    finally:
        for s in subs:
            s.close()
        recorded = recorder.stop().as_dict() if recorder is not None else None
        tool.close()
        for p in procs.values():
            stop_process(p)
    with rec.lock:
        _plots(out, rec, tasks)
        summary = {"site": site, "ok": code == 0, "duration_s": round(time.time() - rec.t0, 1), "nodes": sorted(nodes),
                   "tasks": tasks, "mismatches": rec.mismatches, "contact_events": len(rec.contacts),
                   "contacts_by_robot": {r: sum(c["robot"] == r for c in rec.contacts) for r in ROBOTS},
                   "vision_objects_seen": rec.objects[-10:], "camera_frames": len(rec.frames),
                   "progress": rec.progress, "contacts": rec.contacts,
                   **({"recording": {"file": "demo.mcap", **recorded}} if recorded is not None else {})}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    console.rule("report")
    for t in tasks:
        colour = "green" if t.get("ok") else "red"
        console.print(f"[{colour}]{t['atd']}[/]: "
                      + ", ".join(f"{r}: {o}" for r, o in sorted(t.get("outcomes", {}).items())))
        for r, detail in sorted(t.get("why", {}).items()):
            console.print(f"  {r}: {detail}")
        for c in t.get("corrections", ()):
            console.print(f"  {c['robot']} corrected on its predictor's mismatch: {c['transition']} "
                          f"(t={c['t_sim']:.2f} s)")
        for r, checks in sorted(t.get("physical", {}).items()):
            for c in checks:
                console.print(f"  {r} {c['state']} ({c['object']}): {'ok' if c['ok'] else 'FAILED'}, {c['why']}")
    if code:
        console.print("[red]the demo failed:[/] not every task ended in success on every robot "
                      "with the expected physical result")
    console.print(f"{len(rec.contacts)} contact events; report in {out} (summary.json, timeline.png, contacts.png"
                  + (f", demo.mcap: {recorded['recorded']:.0f} messages)" if recorded is not None else ")"))
    return code
