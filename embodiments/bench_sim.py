"""Benchmark ``sim``: real-time factor of each embodiment's interface stack, kinematics overhead, OMPL planners.

1. Real-time factor (sim seconds per wall second) of each robot's full interface stack:
   physics, gravity compensation, the 200 Hz controllers and mixer, fault monitor, and the
   interface modules (joint state publisher, joint command subscriber, F/T and tactile
   publishers at 200 Hz, ground truth at 50 Hz; messages round-trip through the wire codec
   via FakeIO), while one arm follows a Cartesian line back and forth. Each robot runs in
   its own process pinned to one core; then two robots together: two processes on the two
   cores (separate worlds, lockstep each) and both robots in one world on one core. The
   camera (ray casting, ~40 ms a frame) is measured separately at 5 Hz.
2. Our kinematics wrapper (update + frame pose + Jacobian) vs. the same raw pinocchio calls.
3. KPIECE1 vs. RRTConnect on a fixed set of 7-DoF table problems (tombatossals' left panda
   arm, table with three box obstacles, seeded start/goal pairs, coal collision checking):
   median planning time and success rate.
4. The runtime (``bench_runtime``): the real-time factor of a world node and control nodes
   running their tasks in lockstep, one robot and two robots in one cell, every node in one
   process and each in its own, side by side; the command -> sensor round trip over loopback.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import pathlib
import platform
import time

import numpy as np
import pinocchio as pin
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from contactflow.embodiments import bench_runtime
from contactflow.nodes.stats import rate, rate_text

ROBOTS = ("tombatossals", "melfa", "baxter")


def _pin(core: int | None) -> None:
    if core is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {core % (os.cpu_count() or 1)})


def _stack(robot, with_camera: bool):
    """The interface modules of one robot, set up on FakeIOs."""
    from contactflow.embodiments.modules.camera_publisher import CameraPublisher
    from contactflow.embodiments.modules.ft_publisher import FTPublisher
    from contactflow.embodiments.modules.ground_truth_publisher import GroundTruthPublisher
    from contactflow.embodiments.modules.joint_command_subscriber import JointCommandSubscriber
    from contactflow.embodiments.modules.joint_state_publisher import JointStatePublisher
    from contactflow.embodiments.modules.tactile_publisher import TactilePublisher
    from contactflow.nodes.testing import FakeIO

    mods = [JointStatePublisher("joint_state", robot), JointCommandSubscriber("joint_command", robot),
            GroundTruthPublisher("ground_truth", robot)]
    mods += [FTPublisher(f"ft_{a}", robot, FTPublisher.Params(arm=a)) for a in robot.arms if robot.spec.arm(a).ft]
    mods += [TactilePublisher(f"tactile_{h.name}", robot, TactilePublisher.Params(hand=h.name)) for h in robot.spec.hands if h.pads]
    if with_camera and robot.spec.cameras:
        mods.append(CameraPublisher("camera", robot, CameraPublisher.Params(camera=robot.spec.cameras[0].name)))
    out = []
    for m in mods:
        io = FakeIO(module=m)
        m.setup(io)
        m.start()
        out.append((m, io, 1.0 / m.params.rate_hz))
    return out


def _run_stack(robots, sim_time: float, with_camera: bool = False, warmup: float = 0.3) -> float:
    """Advance the shared world of ``robots`` for ``sim_time`` s with every module; returns the RTF.

    The first ``warmup`` s are not timed (lazy imports, first camera geometry build).
    """
    world = robots[0].world
    stacks = [(r, _stack(r, with_camera)) for r in robots]
    lines = []
    for r in robots:
        arm = r.arm(r.arms[0])
        p0 = arm.ee_pose()
        lines.append((arm, p0))
    due: dict[int, float] = {}
    dt = 1.0 / robots[0].params.control_rate
    t_start = world.time + warmup
    t_end = t_start + sim_time
    k = 0
    t0 = None
    while world.time < t_end:
        if t0 is None and world.time >= t_start:
            t0 = time.perf_counter()
        for arm, p0 in lines:
            if arm.status != arm.status.RUNNING:
                goal = p0.copy()
                goal[1, 3] += 0.1 if k % 2 == 0 else 0.0
                arm.move_pose(goal, speed=0.1)
                k += 1
        world.run(dt)
        for _r, mods in stacks:
            for m, io, period in mods:
                key = id(m)
                if world.time + 1e-9 >= due.get(key, 0.0):
                    io.t = world.time
                    m.step()
                    due[key] = due.get(key, 0.0) + period
                    for port in io.published:
                        del io.published[port][:-1]
    return sim_time / (time.perf_counter() - t0)


def _cpu_text(per_module: dict[str, float], top: int = 5) -> str:
    """The modules that take most of a tick (node/module: ms), the rest summed, and the total."""
    items = list(per_module.items())
    shown = [f"{name.split('/', 1)[-1]} {ms:.2f}" for name, ms in items[:top]]
    rest = sum(ms for _, ms in items[top:])
    return ", ".join(shown + ([f"{len(items) - top} more {rest:.2f}"] if rest else [])) + \
        f" (total {sum(per_module.values()):.2f})"


def _rtf_job(args) -> dict:
    names, sim_time, core, with_camera = args
    _pin(core)
    from contactflow.embodiments.sim_robot import SimRobot
    from contactflow.embodiments.world import World, box

    world = World()
    world.add_table()
    world.add_object(box("cube", (0.05, 0.05, 0.05), (0.6, 0.35, 0.775), mass=0.2))
    robots = []
    for i, n in enumerate(names):
        base = None
        if len(names) > 1:
            from contactflow.embodiments.registry import get
            from contactflow.embodiments.transforms import xyz_rpy_to_matrix

            spec = get(n)
            base = xyz_rpy_to_matrix((spec.base_xyz[0], spec.base_xyz[1] + 1.6 * i, spec.base_xyz[2]))
        robots.append(SimRobot(world, n, name=f"{n}{i}" if len(names) > 1 else None, base=base))
    rtf = _run_stack(robots, sim_time, with_camera)
    return {"robots": list(names), "rtf": rtf, "dof": sum(r.art.articulation.dof for r in robots),
            "failed": any(r.failed for r in robots)}


def _kinematics(n_calls: int) -> dict:
    from contactflow.embodiments.control.kinematics import Kinematics
    from contactflow.embodiments.registry import get

    urdf = str(get("tombatossals").urdf())
    kin = Kinematics(urdf)
    model = pin.buildModelFromUrdf(urdf)
    data = model.createData()
    fid = model.getFrameId("left_grasp")
    rng = np.random.default_rng(0)
    qs = np.clip(rng.uniform(-1, 1, (n_calls, model.nq)), model.lowerPositionLimit, model.upperPositionLimit)
    t0 = time.perf_counter()
    for q in qs:
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        _ = data.oMf[fid].homogeneous
        _ = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)
    raw = (time.perf_counter() - t0) / n_calls
    t0 = time.perf_counter()
    for q in qs:
        kin.update(q)
        _ = kin.frame_pose("left_grasp")
        _ = kin.jacobian("left_grasp")
    wrapped = (time.perf_counter() - t0) / n_calls
    return {"raw_us": raw * 1e6, "wrapper_us": wrapped * 1e6, "overhead": wrapped / raw, "dof": model.nq}


def _stages(profiles) -> dict:
    """Median of each stage of the plans (s), their checks, and the checks per second."""
    med = lambda f: float(np.median([f(p) for p in profiles]))  # noqa: E731
    return {"ends_s": med(lambda p: p.ends), "search_s": med(lambda p: p.search), "simplify_s": med(lambda p: p.simplify),
            "validate_s": med(lambda p: p.validate), "searches": med(lambda p: p.searches),
            "checks": med(lambda p: p.search_checks + p.path_checks), "checks_per_second": med(lambda p: p.checks_per_second),
            "re_searched": int(sum(p.searches > 1 for p in profiles))}


def planning_problems(n: int, seed: int = 7):
    """Fixed 7-DoF table problems: (kin, checker, planner, list of (start, goal))."""
    from contactflow.embodiments.control.kinematics import Kinematics
    from contactflow.embodiments.control.planning import ArmPlanner, CoalChecker, Obstacle
    from contactflow.embodiments.registry import get
    from contactflow.embodiments.transforms import xyz_rpy_to_matrix

    spec = get("tombatossals")
    base = xyz_rpy_to_matrix(spec.base_xyz, spec.base_rpy)
    kin = Kinematics(spec.urdf(), base)
    obstacles = [Obstacle("table", "box", (0.8, 1.4, 0.75), xyz_rpy_to_matrix((0.65, 0.0, 0.375))),
                 Obstacle("wall", "box", (0.3, 0.04, 0.3), xyz_rpy_to_matrix((0.55, 0.3, 0.9))),
                 Obstacle("post", "box", (0.06, 0.06, 0.4), xyz_rpy_to_matrix((0.45, 0.45, 0.95))),
                 Obstacle("shelf", "box", (0.3, 0.3, 0.02), xyz_rpy_to_matrix((0.6, 0.3, 1.2)))]
    checker = CoalChecker(kin, str(spec.urdf()), obstacles, parts=spec.collision_groups)
    arm = spec.arm("left")
    q_fixed = np.clip(np.zeros(kin.nq), kin.lower, kin.upper)
    q_fixed[kin.q_index(arm.joints)] = arm.home
    planner = ArmPlanner(kin, arm.joints, checker.valid, q_fixed)
    rng = np.random.default_rng(seed)
    problems = []
    while len(problems) < n:
        pair = []
        while len(pair) < 2:
            q = rng.uniform(planner.lower, planner.upper)
            kin.update(planner.full(q))
            p = kin.frame_pose(arm.ee_frame)[:3, 3]
            if 0.78 < p[2] < 1.3 and 0.3 < p[0] < 0.8 and planner.valid(q):
                pair.append(q)
        if np.linalg.norm(pair[0] - pair[1]) > 1.0:
            problems.append((pair[0], pair[1]))
    return planner, problems


def run(out_dir: pathlib.Path, quick: bool = False) -> dict:
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    console = Console()
    sim_time = 1.0 if quick else 5.0
    n_problems = 3 if quick else 40  # a p95 over 20 plans is the 19th: one hard problem moves it
    timeout = 1.0 if quick else 5.0
    load = os.getloadavg() if hasattr(os, "getloadavg") else (0.0, 0.0, 0.0)
    # other processes on the shared cores skew every number: the load average is recorded with them
    summary: dict = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "loadavg_1min": load[0]},
                     "sim_time_s": sim_time, "single": {}, "pair": {}}
    ctx = mp.get_context("spawn")
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task("sim bench", total=len(ROBOTS) + 4 + 2 * n_problems + bench_runtime.steps(quick))
        with ctx.Pool(1) as pool:
            for name in ROBOTS:
                summary["single"][name] = pool.apply(_rtf_job, (((name,), sim_time, 0, False),))
                progress.advance(task)
            summary["camera"] = pool.apply(_rtf_job, ((("tombatossals",), sim_time / 2, 0, True),))
            progress.advance(task)
            summary["pair"]["one_world_one_core"] = pool.apply(_rtf_job, ((("tombatossals", "baxter"), sim_time, 0, False),))
            progress.advance(task)
        with ctx.Pool(2) as pool:
            res = pool.map(_rtf_job, [(("tombatossals",), sim_time, 0, False), (("baxter",), sim_time, 1, False)])
            summary["pair"]["two_processes_two_cores"] = {"robots": ["tombatossals", "baxter"],
                                                          "rtf": min(r["rtf"] for r in res),
                                                          "each": [r["rtf"] for r in res]}
            progress.advance(task)
        summary["kinematics"] = _kinematics(500 if quick else 5000)
        progress.advance(task)
        planner, problems = planning_problems(n_problems)
        plans: dict[str, dict] = {}
        for name in ("KPIECE1", "RRTConnect"):
            times, ok, profiles, lengths = [], [], [], []
            for k, (a, b) in enumerate(problems):
                p = planner.plan(a, b, planner=name, timeout=timeout, seed=100 + k)
                ok.append(p.success)
                times.append(p.planning_time)
                profiles.append(p.profile)
                if p.success:
                    lengths.append(p.length)
                progress.advance(task)
            plans[name] = {"success": rate(int(sum(ok)), len(ok)),
                           "median_time_s": float(np.median(times)),
                           "median_time_success_s": float(np.median([t for t, s in zip(times, ok, strict=True) if s])) if any(ok) else None,
                           "p95_time_s": float(np.percentile(times, 95)),
                           "median_length_rad": float(np.median(lengths)) if lengths else None,
                           "problems": len(problems), "timeout_s": timeout, "stages": _stages(profiles)}
        summary["planning"] = plans
        summary["runtime"] = bench_runtime.run(quick, advance=lambda: progress.advance(task), out_dir=out_dir)
    table = Table(title="contactflow bench sim")
    table.add_column("measure")
    table.add_column("value", justify="right")
    for name, r in summary["single"].items():
        table.add_row(f"RTF {name} ({r['dof']} DoF, stack, 1 core)", f"{r['rtf']:.1f}x")
    table.add_row("RTF tombatossals + camera 5 Hz (1 core)", f"{summary['camera']['rtf']:.1f}x")
    table.add_row("RTF tombatossals+baxter, one world, 1 core", f"{summary['pair']['one_world_one_core']['rtf']:.1f}x")
    table.add_row("RTF tombatossals | baxter, 2 processes, 2 cores (min)", f"{summary['pair']['two_processes_two_cores']['rtf']:.1f}x")
    k = summary["kinematics"]
    table.add_row(f"FK+Jacobian raw pinocchio ({k['dof']} DoF)", f"{k['raw_us']:.1f} us")
    table.add_row("FK+Jacobian our wrapper", f"{k['wrapper_us']:.1f} us ({k['overhead']:.2f}x)")
    for name, r in plans.items():
        med = r["median_time_success_s"]
        solved = rate_text(r["success"]["successes"], r["success"]["trials"])
        table.add_row(f"{name}: solved [95 % interval] / median time (solved) / p95",
                      f"{solved} / {1000 * med:.0f} ms / {1000 * r['p95_time_s']:.0f} ms" if med else solved)
        st = r["stages"]
        table.add_row(f"{name}: median ms ends | search | simplify | validate",
                      " | ".join(f"{1000 * st[k]:.0f}" for k in ("ends_s", "search_s", "simplify_s", "validate_s")))
        table.add_row(f"{name}: median checks, checks/s, plans searched twice, path length",
                      f"{st['checks']:.0f}, {st['checks_per_second']:,.0f}/s, {st['re_searched']}, "
                      f"{r['median_length_rad'] or float('nan'):.2f} rad")
    for label, row in summary["runtime"]["rtf"].items():
        one, split = row["one_process"], row["split"]
        table.add_row(f"runtime RTF, {label}: one process | split (vs one)",
                      f"{one['rtf']:.1f}x | {split['rtf']:.1f}x ({row['split_vs_one']:.2f})")
        table.add_row(f"runtime, {label}: the same events in both layouts | overruns",
                      f"{'yes' if row['repeated'] else 'NO'} ({one['events']} events) | "
                      f"{one['overruns']} | {split['overruns']}")
        table.add_row(f"runtime, {label}, split: CPU ms per tick, by module", _cpu_text(split["cpu_ms_per_tick"]))
    rows = summary["runtime"]["rtf"]
    for label in [k for k in rows if f"{k}, pipelined" in rows]:
        plain, piped = rows[label]["split"]["rtf"], rows[f"{label}, pipelined"]["split"]["rtf"]
        table.add_row(f"runtime RTF, {label}, split: pipelined vs plain", f"{piped:.1f}x vs {plain:.1f}x "
                                                                          f"({piped / plain if plain else 0.0:.2f})")
    rt = summary["runtime"]["round_trip"]
    table.add_row(f"command -> sensor round trip, loopback ({rt['ticks']} ticks): p50 / p99",
                  f"{rt['p50_ms']:.2f} / {rt['p99_ms']:.2f} ms")
    console.print(table)
    console.print(f"load average at start: {load[0]:.1f} on {os.cpu_count()} cores")
    (out_dir / "sim.json").write_text(json.dumps(summary, indent=2))
    return summary
