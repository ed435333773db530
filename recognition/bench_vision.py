"""Benchmark of the 3D vision pipeline rate at 640x480, per stage in this process and end to end on the runtime (§6.3.3).

``local``: frames are ray-cast depth images of table scenes (rendering is not timed), run on
one core. The pipeline runs as in the system: the plane detector refits at 1 Hz on a 30 Hz
frame clock, so its cost is amortised; the refit time is reported on its own. The module
chain row adds the wire round-trips of every message (FakeIO encodes and decodes each one).

``runtime``: a world node (tombatossals at a table with five objects, real-time clock)
streams its Kinect's depth frames at 30 Hz on ``robot/<r>/depth`` and a vision3d node
(``layout.vision_node``) segments them over zenoh, each node a process of its own; the
bench listens to both streams and measures, per fresh frame, the wall time from the frame's
stamp to the arrival of the objects cut from it, the frames processed and dropped per second
of wall time, and whether the clusters match the objects on the table. ``both`` also runs
the local pipeline on the runtime's cell and prints the two side by side.
"""

from __future__ import annotations

import json
import math
import os
import pathlib
import tempfile
import threading
import time
from dataclasses import dataclass

import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from contactflow.nodes.params import ParamError
from contactflow.nodes.testing import FakeIO
from contactflow.nodes.wire import stamp
from contactflow.recognition.messages import PointCloud, RobotSpheres, depth_image, nd
from contactflow.recognition.pipeline import (
    DistanceFn,
    SegmentationPipeline,
    culled_distance,
    sphere_distance,
)
from contactflow.recognition.services.cloud_builder import CloudBuilder
from contactflow.recognition.services.cluster_extractor import ClusterExtractor
from contactflow.recognition.services.plane_detector import PlaneDetector
from contactflow.recognition.services.roi_filter import RoiFilter
from contactflow.recognition.services.self_filter import SelfFilter
from contactflow.recognition.synthetic import sphere_mesh
from contactflow.recognition.testing import Placed, TableScene

FRAME_RATE = 30.0  # Hz, camera clock
STAGES = ("cloud", "plane", "roi", "self", "cluster", "total")
EXECUTORS = ("local", "runtime", "both")
ROBOT = "tombatossals"
CELL = "runtime cell: tombatossals at home + 5 objects"


def _arm() -> tuple[np.ndarray, np.ndarray]:
    """A spherical model of an arm reaching over the table (40 spheres)."""
    t = np.linspace(0.0, 1.0, 40)
    centres = np.column_stack((0.1 + 0.45 * t, -0.35 + 0.3 * t, 0.5 - 0.38 * t))
    radii = 0.06 - 0.025 * t
    return centres, radii


def scenes() -> dict[str, tuple[TableScene, tuple[np.ndarray, np.ndarray] | None]]:
    rng = np.random.default_rng(6)
    clutter = []
    for i in range(10):
        xy = (0.33 + 0.11 * (i % 5) + rng.uniform(-0.01, 0.01), -0.15 + 0.25 * (i // 5) + rng.uniform(-0.02, 0.02))
        kind = ("box", "cylinder", "sphere")[i % 3]
        size = {"box": (0.06, 0.05, 0.1), "cylinder": (0.03, 0.12, 0.0), "sphere": (0.035, 0.0, 0.0)}[kind]
        clutter.append(Placed(kind, size, xy, float(rng.uniform(0, 3))))
    arm = _arm()
    three = [Placed("box", (0.06, 0.05, 0.12), (0.45, 0.10), 0.3), Placed("box", (0.08, 0.08, 0.08), (0.65, -0.15)),
             Placed("cylinder", (0.035, 0.15, 0.0), (0.55, 0.25))]
    return {
        "3 objects": (TableScene(three), None),
        "10 objects": (TableScene(clutter), None),
        "3 objects + arm (self filter)": (TableScene(three, extra=[sphere_mesh(r, c) for c, r in zip(*arm, strict=True)]),
                                          arm),
    }


def _stats(values: list[float]) -> dict[str, float]:
    a = np.array(values) * 1000.0
    med = float(np.median(a))
    return {"mean_ms": float(a.mean()), "median_ms": med, "p5_ms": float(np.percentile(a, 5)),
            "p95_ms": float(np.percentile(a, 95)),
            "hz": float(1000.0 / a.mean()) if a.mean() > 0 else float("inf"),
            "hz_median": 1000.0 / med if med > 0 else float("inf")}


@dataclass
class Frames:
    """Pre-rendered depth frames of one scene, with the robot's distance function."""

    depths: list[np.ndarray]
    K: np.ndarray
    pose: np.ndarray
    distance: DistanceFn | None = None
    spheres: tuple[np.ndarray, np.ndarray] | None = None
    objects: int = 0  # objects on the table (the right number of clusters)
    joints: tuple[list[str], np.ndarray] | None = None  # robot joint names and positions


def synthetic_frames(scene: TableScene, arm) -> Frames:
    return Frames([scene.render(0.0015, seed) for seed in range(4)], scene.K, scene.pose,
                  sphere_distance(*arm, cutoff=0.02) if arm is not None else None, arm, len(scene.objects))


def table_objects() -> list:
    """Five objects on the table in front of tombatossals (the simulator scenes' and the runtime cell's)."""
    from contactflow.embodiments.world import bottle, box, cylinder, mug, sphere

    return [box("box", (0.06, 0.05, 0.12), xyz=(0.55, 0.12, 0.81)),
            cylinder("can", 0.035, 0.12, xyz=(0.62, -0.12, 0.811)),
            sphere("ball", 0.035, xyz=(0.5, -0.02, 0.786)),
            mug("mug", xyz=(0.7, 0.05, 0.801)),
            bottle("bottle", xyz=(0.5, -0.22, 0.83))]


def _table_robot():
    from contactflow.embodiments.sim_robot import SimRobot
    from contactflow.embodiments.world import World, WorldParams

    world = World(WorldParams())
    world.add_table()
    for spec in table_objects():
        world.add_object(spec)
    return SimRobot(world, ROBOT)


def simulated_frames() -> Frames:
    """A frame of the simulator's camera: tombatossals reaching over a table with five
    objects; the robot's own spherical model (Appendix B) is the self filter."""
    robot = _table_robot()
    robot.step(0.1)
    # the right hand reaches over the objects, so the arm is inside the region of interest
    arm = robot.arm("right")
    T = arm.ee_pose().copy()
    T[:3, 3] = (0.6, -0.05, 1.0)
    arm.move_pose(T, speed=0.5)
    arm.wait(5.0)
    robot.step(0.1)
    frame = robot.camera()
    model = robot.spherical
    centres, radii = _stope_spheres(model)
    names, q, _, _ = robot.joint_state()
    fn = culled_distance(model.C1, model.C2, model.r1, model.r2, 0.02)
    return Frames([frame.depth], frame.K, frame.T_world_cam, fn, (centres, radii), 5, (names, q))


def cell_frames() -> Frames:
    """Frames of the runtime's cell rendered in this process: tombatossals at home (its arms out of the
    region of interest, as the vision node has no self filter) over the five objects."""
    robot = _table_robot()
    depths = []
    for _ in range(4):
        robot.step(0.3)
        depths.append(robot.camera().depth)
    frame = robot.camera()
    return Frames(depths, frame.K, frame.T_world_cam, None, None, len(table_objects()))


def _stope_spheres(model, per: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Spheres along each s-tope of the spherical model, for the RobotSpheres message."""
    t = np.linspace(0.0, 1.0, per)[None, :, None]
    centres = model.C1[:, None, :] * (1 - t) + model.C2[:, None, :] * t
    radii = model.r1[:, None] * (1 - t[..., 0]) + model.r2[:, None] * t[..., 0]
    return centres.reshape(-1, 3), radii.reshape(-1)


def bench_pipeline(frames_in: Frames, frames: int) -> dict:
    """Stage times in CPU seconds of this process (pinned to one core, so other load on
    the machine does not count), and the wall-clock total alongside."""
    pipe = SegmentationPipeline(clock=time.process_time)
    timings: dict[str, list[float]] = {k: [] for k in STAGES}
    refits, wall, counts, right = [], [], {}, 0
    for i in range(frames):
        t = i / FRAME_RATE
        refit = pipe.planes.due(t)
        w0 = time.perf_counter()
        res = pipe.process_depth(frames_in.depths[i % len(frames_in.depths)], frames_in.K, frames_in.pose, t,
                                 frames_in.distance)
        wall.append(time.perf_counter() - w0)
        for k in STAGES:
            timings[k].append(res.timings[k])
        if refit:
            refits.append(res.timings["plane"])
        counts = res.counts
        right += counts["clusters"] == frames_in.objects
    out = {k: _stats(v) for k, v in timings.items()}
    out["wall_total"] = _stats(wall)
    out["plane_refit"] = _stats(refits)
    out["points"] = counts
    out["objects"] = frames_in.objects
    out["clusters_right"] = right
    return out


def bench_modules(frames_in: Frames, frames: int) -> dict:
    """The five services chained through FakeIO (every message encoded and decoded)."""
    depths, arm = frames_in.depths, frames_in.spheres
    mods = [CloudBuilder("cloud"), PlaneDetector("plane"), RoiFilter("roi"), SelfFilter("self"),
            ClusterExtractor("clusters")]
    ios = [FakeIO(module=m) for m in mods]
    for m, io in zip(mods, ios, strict=True):
        m.setup(io)
        m.start()
    spheres = RobotSpheres(centers=nd(arm[0]), radii=nd(arm[1])) if arm else None
    times = []
    for i in range(frames):
        t = i / FRAME_RATE
        t0 = time.process_time()
        frame = stamp(depth_image(depths[i % len(depths)], frames_in.K, frames_in.pose), "site/cam/camera/depth", i + 1, t)
        ios[0].feed("depth", frame)
        mods[0].step()
        cloud = ios[0].published["cloud"][-1]
        if i % int(FRAME_RATE) == 0:
            ios[1].feed("cloud", cloud)
            mods[1].step()
            ios[2].feed("roi", ios[1].published["roi"][-1])
            ios[4].feed("plane", ios[1].published["plane"][-1])
        ios[2].feed("cloud", cloud)
        mods[2].step()
        ios[3].feed("cloud", ios[2].published["cloud"][-1])
        if spheres is not None:
            ios[3].feed("spheres", spheres)
        mods[3].step()
        ios[4].feed("cloud", ios[3].published["cloud"][-1])
        mods[4].step()
        times.append(time.process_time() - t0)
        for io in ios:
            io.published.clear()
    return _stats(times)


CHAIN = ("cloud", "roi", "self")  # the vision node's modules between the depth frame and the objects (their "cloud" port)


class _ChainProbe:
    """The bench's session on the site: each depth frame's wall stamp, when each stage's cloud cut from it
    arrived, and when its objects arrived."""

    def __init__(self, transport, depth_key: str, objects_key: str, stage_keys: dict[str, str]) -> None:
        self._lock = threading.Lock()
        self.frames: dict[int, tuple[float, float]] = {}  # depth seq -> the frame's (wall stamp (s, epoch), sim stamp)
        self.objects: dict[int, tuple[float, int]] = {}  # depth seq -> (arrival wall s, clusters)
        self.sent: dict[int, float] = {}  # depth seq -> when its objects were published (wall s)
        self.stages: dict[str, dict[int, float]] = {s: {} for s in stage_keys}  # stage -> depth seq -> published (wall s)
        self._subs = [transport.subscribe(depth_key, self._on_depth), transport.subscribe(objects_key, self._on_objects)]
        self._subs += [transport.subscribe(key, self._on_stage(stage)) for stage, key in stage_keys.items()]

    def _on_depth(self, key: str, payload: bytes) -> None:
        from contactflow.embodiments.messages import DepthImage
        from contactflow.nodes.wire import decode

        hdr = decode(payload, DepthImage, key).hdr
        with self._lock:
            self.frames[hdr.seq] = (hdr.t_wall, hdr.t_sim)

    def _on_stage(self, stage: str):
        def on(key: str, payload: bytes) -> None:
            from contactflow.nodes.wire import decode

            msg = decode(payload, PointCloud, key)
            with self._lock:
                self.stages[stage].setdefault(msg.depth_frame.seq, msg.hdr.t_wall)
        return on

    def _on_objects(self, key: str, payload: bytes) -> None:
        from contactflow.nodes.wire import decode
        from contactflow.recognition.messages import SegmentedObjects

        now = time.time()  # epoch, as the world's stamps on this machine
        msg = decode(payload, SegmentedObjects, key)
        with self._lock:
            self.objects.setdefault(msg.depth_frame.seq, (now, len(msg.objects)))
            self.sent.setdefault(msg.depth_frame.seq, msg.hdr.t_wall)

    def snapshot(self) -> tuple[dict[int, tuple[float, float]], dict[int, tuple[float, int]], dict[str, dict[int, float]]]:
        """Frames, objects, and when each stage published its output of each frame (objects included)."""
        with self._lock:
            return dict(self.frames), dict(self.objects), {**{k: dict(v) for k, v in self.stages.items()},
                                                          "objects": dict(self.sent)}

    def close(self) -> None:
        for sub in self._subs:
            sub.close()


def _hops(frames: dict[int, tuple[float, float]], stages: dict[str, dict[int, float]],
          arrived: dict[int, float]) -> tuple[dict[str, dict[str, float]], int]:
    """Each hop's median and mean ms over the processed frames the bench heard every stage of (and how many
    those are): from the frame's stamp to the cloud module's output, on from output to output (each stamped
    when its module published it), and from the objects' publication to their arrival at the bench.

    The means add up to the mean latency of those frames; the medians need not: under load a frame
    waits long at one stage or another, so each hop's median stays short while most totals are long.
    """
    seqs = [q for q in sorted(arrived) if all(q in stages[s] for s in (*CHAIN, "objects"))]
    chain = [("frame", {q: frames[q][0] for q in seqs}), *((s, stages[s]) for s in (*CHAIN, "objects")),
             ("bench", arrived)]
    out = {}
    for (a, ta), (b, tb) in zip(chain[:-1], chain[1:], strict=True):
        d = np.array([(tb[q] - ta[q]) * 1e3 for q in seqs]) if seqs else np.full(1, math.nan)  # none: nan
        out[f"{a}->{b}"] = {"median": float(np.median(d)), "mean": float(d.mean())}
    return out, len(seqs)


def _latency(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    a = np.array(values) * 1000.0
    return {"median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)), "mean_ms": float(a.mean()),
            "min_ms": float(a.min()), "max_ms": float(a.max())}


def bench_runtime(folder: pathlib.Path, seconds: float, camera_hz: float = FRAME_RATE, warmup: float = 60.0) -> dict:
    """The runtime's figures over ``seconds`` of wall time, once the first objects came (the plane is known).

    A frame counts when the world published it inside the window; it is processed when the
    objects cut from it arrived (the bench waits a second past the window for those in flight).
    """
    from contactflow.embodiments.layout import (
        start_nodes,
        stop_nodes,
        vision_node,
        world_node,
        write_cell,
    )
    from contactflow.nodes.procs import free_port, wait_for

    cell = write_cell(folder / "cell.yaml", ROBOT, table_objects())
    endpoint, site = f"tcp/127.0.0.1:{free_port()}", f"vision{free_port()}"
    world = world_node(site, cell, clock="realtime", listen=endpoint, camera_hz=camera_hz, ground_truth_hz=0.0)
    vision = vision_node(site, ROBOT, connect=(endpoint,))
    started, watch = start_nodes(folder, [world, vision], site, endpoint, processes=True)
    probe = _ChainProbe(watch.t, watch.ks.robot(ROBOT, "depth"), watch.ks.output(ROBOT, vision["node"], "objects", "objects"),
                        {s: watch.ks.output(ROBOT, vision["node"], s, "cloud") for s in CHAIN})
    try:
        if not wait_for(lambda: bool(probe.snapshot()[1]), warmup):
            raise TimeoutError(f"bench vision: no objects from the vision node within {warmup:g} s (see {folder})")
        t0 = time.time()
        time.sleep(seconds)
        t1 = time.time()
        time.sleep(1.0)
        frames, objects, stages = probe.snapshot()
    finally:
        probe.close()
        stop_nodes(started, watch, processes=True)
    window = {seq: t for seq, (t, _) in frames.items() if t0 <= t < t1}
    done = {seq: objects[seq] for seq in window if seq in objects}
    latency = [done[seq][0] - window[seq] for seq in sorted(done)]
    hops, heard = _hops(frames, stages, {seq: t for seq, (t, _) in done.items()})
    first, last = (frames[seq] for seq in (min(window), max(window))) if len(window) > 1 else ((0.0, 0.0),) * 2
    rtf = (last[1] - first[1]) / (last[0] - first[0]) if last[0] > first[0] else 0.0
    clusters = [n for _, n in done.values()]
    objs = len(table_objects())
    span = t1 - t0
    # where a dropped frame was lost: the first stage that published nothing cut from it
    lost_at = dict.fromkeys((*CHAIN, "objects"), 0)
    for seq in window:
        if seq not in done:
            lost_at[next(s for s in lost_at if seq not in stages[s])] += 1
    return {"seconds": span, "camera_hz": camera_hz, "frames": len(window), "processed": len(done),
            "dropped": len(window) - len(done), "lost_at": lost_at, "world_rtf": rtf, "frames_hz": len(window) / span, "processed_hz": len(done) / span,
            "latency": _latency(latency), "hops_ms": hops, "hops_frames": heard,
            "objects": objs,
            "clusters_right": sum(n == objs for n in clusters), "clusters_seen": sorted(set(clusters))}


def _pin_to_one_core() -> dict[int, set[int]]:
    """Pin every thread of this process (open3d's OpenMP pool included) to one core."""
    tasks = [int(t) for t in os.listdir("/proc/self/task")] if os.path.isdir("/proc/self/task") else [0]
    core = {min(os.sched_getaffinity(0))}
    old = {}
    for tid in tasks:
        try:
            old[tid] = os.sched_getaffinity(tid)
            os.sched_setaffinity(tid, core)
        except OSError:
            old.pop(tid, None)
    return old


def _unpin(old: dict[int, set[int]]) -> None:
    for tid, cpus in old.items():
        try:
            os.sched_setaffinity(tid, cpus)
        except OSError:
            continue


def run(out_dir: pathlib.Path, quick: bool = False, executor: str = "local") -> dict:
    if executor not in EXECUTORS:
        raise ParamError(f"bench vision: --executor {executor!r} is not one of {list(EXECUTORS)}")
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    console = Console()
    frames = 15 if quick else 300
    summary: dict = {"resolution": [640, 480], "frame_rate": FRAME_RATE, "goal_hz": 30.0, "quick": quick,
                     "executor": executor}
    lines = ["# 3D vision pipeline at 640x480", ""]
    if executor != "runtime":
        summary.update(_run_local(frames, console, lines))
    if executor != "local":
        with (tempfile.TemporaryDirectory(prefix="bench-vision-") as d,
              console.status("vision chain on the runtime (world and vision3d node processes)")):
            summary["runtime"] = bench_runtime(pathlib.Path(d), 3.0 if quick else 30.0)
        if executor == "both":
            pinned = _pin_to_one_core()
            try:
                summary["cell_local"] = bench_pipeline(cell_frames(), frames)
            finally:
                _unpin(pinned)
        _compare(summary, console, lines)
    (out_dir / "vision.json").write_text(json.dumps(summary, indent=1))
    (out_dir / "vision.md").write_text("\n".join(lines) + "\n")
    return summary


def _compare(summary: dict, console: Console, lines: list[str]) -> None:
    """The runtime's end-to-end figures, beside the local pipeline's on the same cell (``both``)."""
    rt, loc = summary["runtime"], summary.get("cell_local")
    lat = rt["latency"] or {}

    def ms(x: float | None) -> str:
        return "-" if x is None else f"{x:.1f}"

    rows = [("frames", f"{summary['frames']} (4 rendered, cycled)" if loc else None,
             f"{rt['frames']} published in {rt['seconds']:.1f} s"),
            ("camera Hz (wall)", "- (offline)" if loc else None, f"{rt['frames_hz']:.1f} (asked {rt['camera_hz']:g} of sim time, "
             f"world at {rt['world_rtf']:.2f}x real time)"),
            ("processed Hz (wall)", f"{loc['wall_total']['hz']:.1f} (back to back)" if loc else None,
             f"{rt['processed_hz']:.1f}"),
            ("dropped frames", "0" if loc else None, f"{rt['dropped']}/{rt['frames']}"
             + (" (lost at " + ", ".join(f"{k} {v}" for k, v in rt["lost_at"].items() if v) + ")" if rt["dropped"] else "")),
            ("latency median ms", f"{ms(loc['wall_total']['median_ms'])} (pipeline)" if loc else None,
             f"{ms(lat.get('median_ms'))} (stamp -> objects)"),
            ("latency p95 ms", ms(loc["wall_total"]["p95_ms"]) if loc else None, ms(lat.get("p95_ms"))),
            ("per hop, median (mean) ms", "-" if loc else None,
             ", ".join(f"{h} {v['median']:.1f} ({v['mean']:.1f})" for h, v in rt["hops_ms"].items())),
            ("clusters = objects", f"{loc['clusters_right']}/{summary['frames']}" if loc else None,
             f"{rt['clusters_right']}/{rt['processed']} (seen {rt['clusters_seen']})")]
    t = Table(title=f"3D vision on the {CELL} (wall time)")
    t.add_column("")
    if loc:
        t.add_column("local (one core, in process)")
    t.add_column("runtime (world -> vision3d node over zenoh)")
    lines += ["", f"## {CELL}", "",
              "Runtime: the world node streams its Kinect's depth at 30 Hz (real-time clock), the vision3d node "
              "segments it; latency from the frame's stamp to the arrival of its objects at the bench. "
              "Local: the same pipeline on frames of the same cell, one core, back to back.", "",
              "| | " + ("local | " if loc else "") + "runtime |", "|---|" + ("---|" if loc else "") + "---|"]
    for name, local, runtime in rows:
        cells = [name, *([local] if loc else []), runtime]
        t.add_row(*cells)
        lines.append("| " + " | ".join(cells) + " |")
    console.print(t)


def _run_local(frames: int, console: Console, lines: list[str]) -> dict:
    """The per-stage figures of every scene in this process (the local table)."""
    results = {}
    all_scenes = {name: synthetic_frames(scene, arm) for name, (scene, arm) in scenes().items()}
    all_scenes["simulator camera, tombatossals + 5 objects"] = simulated_frames()
    pinned = _pin_to_one_core()
    try:
        with Progress(console=console, transient=True) as progress:
            task = progress.add_task("vision pipeline at 640x480", total=2 * len(all_scenes))
            for name, fr in all_scenes.items():
                results[name] = bench_pipeline(fr, frames)
                progress.advance(task)
                results[name]["module_chain"] = bench_modules(fr, max(frames // 3, 10))
                progress.advance(task)
    finally:
        _unpin(pinned)
    t = Table(title="3D vision pipeline, 640x480, one core (median CPU ms per frame)")
    t.add_column("scene")
    for k in STAGES:
        t.add_column(k)
    t.add_column("Hz")
    t.add_column("Hz (median)")
    t.add_column("wall Hz")
    t.add_column("plane refit")
    t.add_column("chain Hz")
    t.add_column("clusters/objects")
    lines += ["Median CPU ms per stage of the process pinned to one core (the plane stage amortises the 1 Hz "
              "refit); Hz from the mean and the median CPU total; wall Hz from the wall-clock total, which "
              "other load on the machine inflates. Module chain: the five services through FakeIO (every "
              "message encoded and decoded), CPU time.", "",
              "| scene | " + " | ".join(STAGES) + " | Hz | Hz (median) | wall Hz | plane refit (1 Hz) | module chain Hz "
             "| clusters/objects |",
              "|---|" + "---|" * (len(STAGES) + 6)]
    for name, r in results.items():
        row = [f"{r[k]['median_ms']:.2f}" for k in STAGES]
        extra = [f"{r['total']['hz']:.0f}", f"{r['total']['hz_median']:.0f}", f"{r['wall_total']['hz']:.0f}",
                 f"{r['plane_refit']['median_ms']:.1f} ms", f"{r['module_chain']['hz']:.0f}",
                 f"{r['points']['clusters']}/{r['objects']}"]
        t.add_row(name, *row, *extra)
        lines.append(f"| {name} | " + " | ".join(row + extra) + " |")
    console.print(t)
    return {"frames": frames, "scenes": results, "min_total_hz": min(r["total"]["hz"] for r in results.values())}
