"""Node configurations of the runtime layout: a world node, and a control node per robot (thesis §2.2, App. A).

The world node hosts the ``world`` module (the cell: robots, table, objects). A robot's
control node hosts, with the node's clock in lockstep with the world, the task module and
one module per primitive type its tasks use (a small pool of each, so parallel branches and
helpers run side by side), each configured with the robot's embodiment profile. A robot's
vision node segments the depth stream its world publishes into the objects its control
node's ``detect_objects`` modules select among (``inputs=VISION_INPUTS``). The
configurations are plain node documents (``nodes.procs.write_config`` writes one): the same
document runs in a process of its own (``contactflow node``) or beside others in one.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from contactflow.embodiments.messages import ObjectPoses
from contactflow.fusion.messages import ContactEventMsg
from contactflow.nodes.messages import Clock, EventMsg, StatusMsg
from contactflow.nodes.status import Event
from contactflow.nodes.task_module import TaskProgressMsg
from contactflow.nodes.taskgraph import NodeKind, TaskGraph
from contactflow.nodes.wire import decode

CELLS = Path(__file__).parent / "cells"


def primitive_types(tasks: Mapping[str, TaskGraph], main: str) -> list[str]:
    """Every primitive type ``main`` runs, through nested tasks, parallel branches and helpers."""
    seen: set[str] = set()
    out: set[str] = set()
    todo = [main]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        for node in tasks[name].nodes.values():
            for n in (node, *node.branches):
                if n.kind is NodeKind.PRIMITIVE:
                    out.add(n.type)
                elif n.kind is NodeKind.TASK:
                    todo.append(n.type)
                out.update(h.type for h in n.helpers)
    return sorted(out)


def primitive_modules(robot: str, embodiment: str = "", types: list[str] | None = None, pool: int = 2) -> list[dict]:
    """Module entries hosting ``pool`` modules of each primitive type (``T``, ``T_2``, ...) for ``robot``,
    configured with its home's overrides; ``types`` defaults to every primitive type its
    translations may run (its capabilities)."""
    from contactflow.embodiments import registry
    from contactflow.nodes.module import Layer
    from contactflow.nodes.registry import layer_types

    home = registry.home(embodiment or robot)
    if types is None:
        types = sorted(home.spec.capabilities.primitives & layer_types(Layer.PRIMITIVE))
    defaults = home.overrides
    out = []
    for t in types:
        params = {k: _plain(v) for k, v in defaults.get(t, {}).items()}
        out += [{"name": t if k == 1 else f"{t}_{k}", "type": t, "robot": robot, "autostart": False,
                 **({"params": params} if params else {})} for k in range(1, pool + 1)]
    return out


def contact_modules(robot: str, embodiment: str = "", predictor: bool = False) -> list[dict]:
    """Module entries of a robot's own contact fusion (thesis ch. 4) on its control node: the tactile, wrist F/T
    and (a multi-finger hand) finger pose generators of every arm with a hand (``contact_cues``), the robot's
    posed model (``model``, from the joints the world publishes) feeding motion support (§4.5.1: where the hands
    go next) and null hypotheses (§4.2.1: the space they swept), with ``predictor`` (the node hosts the robot's
    predictor) the simulator support of its predicted hand contacts (§4.5.2), and ``contact_fusion`` over them
    all, whose contacts and events go out on ``contacts/fused/<robot>/...`` (what ``wait_event`` with
    ``sensor: fused`` reads)."""
    from contactflow.embodiments import registry
    from contactflow.fusion.station import hand_links

    spec = registry.home(embodiment or robot).spec
    arms = [a.name for a in spec.arms if a.hand]
    hands = list(dict.fromkeys(p for a in arms for p in hand_links(spec, a)))
    # a station's pace (thesis: fusion cycles at ~6-30 Hz): every generator each cycle, a contact broken 0.3 s
    # after its last sight (a held object's contacts flicker between the pads and the wrist's bi-spheres)
    pace = {"autostart": True, "robot": robot}
    cues = [{"name": f"cues_{a}", "type": "contact_cues", **pace, "params": {"arm": a, "rate_hz": 20.0}} for a in arms]
    model = {"name": "model", "type": "contactflow.embodiments.modules.model_publisher:RobotModelPublisher", **pace,
             "params": {"rate_hz": 20.0}}
    on_model = {"robot_model": "model.robot_model"}
    generators = [{"name": "motion", "type": "motion_support_hypotheses", **pace, "inputs": on_model,
                   "params": {"robot": robot, "rate_hz": 20.0, "links": hands}},
                  # null where the hands are now, not where they were: a held object moves with the hand,
                  # into the space its trailing side just left
                  {"name": "null", "type": "null_hypotheses", **pace, "inputs": on_model,
                   "params": {"robot": robot, "rate_hz": 20.0, "links": hands, "memory": 0.0}}]
    if predictor:  # support where the predictor's hands touch what the robot believes, its pose error spread
        generators.append({"name": "simulator", "type": "simulator_support_hypotheses", **pace,
                           "params": {"robot": robot, "rate_hz": 20.0, "dilate": 0.02}})
    return [*cues, model, *generators,
            # the posed model tells where on the hand each contact lies (finger, palm, held object)
            {"name": "contacts", "type": "contact_fusion", **pace, "inputs": on_model,
             "params": {"robot": robot, "sources": f"{robot}/*", "publish_hypotheses": False, "timeout": 0.3,
                        "wait_timeout": 0.05, "source_timeout": 0.5, "hold": 0.3}}]


def cell_map_module(cell: str, robots: tuple[str, ...], **params: Any) -> dict:
    """The module entry of a cell's contact map (``cell_fusion``): the clouds of every generator of ``robots`` fused
    into one map, out on ``contacts/fused/<cell>/...``, at the pace of a robot's own fusion (:func:`contact_modules`);
    ``params``: more of its Params (a ``map_region``: the objects its contacts touch there)."""
    return {"name": "cell_map", "type": "cell_fusion", "robot": "site", "autostart": True,
            "params": {"robot": cell, "robots": list(robots), "publish_hypotheses": False, "timeout": 0.3,
                       "wait_timeout": 0.05, "source_timeout": 0.5, "hold": 0.3, **_plain(params)}}


def _plain(v: Any) -> Any:
    """Plain YAML values: tuples and numpy arrays become lists, numpy scalars numbers."""
    if hasattr(v, "tolist"):
        v = v.tolist()
    if isinstance(v, tuple | list):
        return [_plain(x) for x in v]
    if isinstance(v, Mapping):
        return {k: _plain(x) for k, x in v.items()}
    return v


def zenoh(listen: str = "", connect: tuple[str, ...] = ()) -> dict[str, Any]:
    z: dict[str, Any] = {"mode": "peer", "multicast_scouting": False}
    if listen:
        z["listen"] = [listen]
    if connect:
        z["connect"] = list(connect)
    return z


def world_node(site: str, scene_file: str | Path, node: str = "world", clock: str = "lockstep",
               listen: str = "", connect: tuple[str, ...] = (), **params: Any) -> dict[str, Any]:
    """The world node: one ``world`` module building the cell of ``scene_file`` (``params``: its Params)."""
    params = {k: _plain(v) for k, v in params.items()}
    return {"site": site, "node": node, "clock": "wall", "zenoh": zenoh(listen, connect),
            "modules": [{"name": "world", "type": "world",
                         "params": {"scene_file": str(scene_file), "clock": clock, **params}}]}


def control_node(site: str, robot: str, embodiment: str, task_file: str | Path, task: str = "",
                 plan: Mapping[str, Any] | None = None, node: str = "", clock: str = "lockstep",
                 listen: str = "", connect: tuple[str, ...] = (), pool: int = 2,
                 autostart: bool = False, inputs: Mapping[str, Mapping[str, str]] | None = None,
                 contacts: bool = False, predictor: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A robot's control node: the task module and the primitive modules of its task, in lockstep;
    with ``contacts``, the robot's contact fusion too (:func:`contact_modules`); with ``predictor``
    (its params, e.g. ``{"belief": scene_file}``), the robot's predictor (thesis ch. 5).

    With ``autostart`` the task starts with the node, at the first tick it steps (a world
    that waits for the node makes that tick 0); else on a RUN control message. ``inputs``
    wires the primitive modules (and the predictor, type ``predictor``) by type, as a manifest's
    ``primitive_inputs``: port -> ``[robot/]module.port`` or a key expression.
    """
    from contactflow.nodes.taskfile import load_tasks

    tasks, main = load_tasks(str(task_file))
    name = task or main
    modules = primitive_modules(robot, embodiment, primitive_types(tasks, name), pool)
    if contacts:
        modules += contact_modules(robot, embodiment, predictor=predictor is not None)
    if predictor is not None:
        modules.append({"name": "predictor", "type": "predictor", "robot": robot, "autostart": True,
                        "params": {k: _plain(v) for k, v in predictor.items()}})
    for m in modules:
        if m["type"] in (inputs or {}):
            m["inputs"] = dict(inputs[m["type"]])
    modules.append({"name": "task", "type": "task", "robot": robot, "autostart": autostart,
                    "params": {"task_file": str(task_file), "task": name, "robot": robot,
                               "plan": yaml.safe_dump(_plain(dict(plan or {})), default_flow_style=True).strip(),
                               "pool": pool}})
    return {"site": site, "node": node or f"control_{robot}", "clock": clock, "zenoh": zenoh(listen, connect),
            "modules": modules}


VISION_INPUTS = {"detect_objects": {"objects": "objects.objects", "plane": "plane.plane"}}
"""A control node's inputs (``control_node(inputs=...)``) that make its detect_objects read the robot's vision node."""


def vision_node(site: str, robot: str, node: str = "", listen: str = "", connect: tuple[str, ...] = (),
                clock: str = "lockstep", cell: str = "", embodiment: str = "", contacts: bool = False) -> dict[str, Any]:
    """A robot's vision3d node (thesis §6.3.3): cloud -> plane -> ROI -> self filter -> objects, fed by the depth
    stream and the joints its world publishes (the self filter poses the spherical model of ``embodiment``,
    default ``robot``, at its registry base). With ``contacts`` (the robot's control node runs its contact fusion,
    :func:`contact_modules`) it also runs the range generator (§4.4.4: the occupancy grid of the objects it sees
    above the support plane, the posed model of the robot's control node as the virtual contact sensor) on the same
    depth stream, its clouds on ``contacts/<robot>/range``, which the robot's fusion plugs beside its other
    generators.

    The world streams depth frames only with its ``camera_hz`` param set. In lockstep (the
    default) the world waits for the chain each tick, so a frame's objects reach a task at the
    same simulated time whatever the CPUs' speed: a seeded run with vision repeats exactly.
    """
    from contactflow.nodes.keys import KeySpace

    svc = "contactflow.recognition.services"
    ks = KeySpace(site)
    modules = [
        {"name": "cloud", "type": f"{svc}.cloud_builder:CloudBuilder", "inputs": {"depth": ks.robot(robot, "depth")}},
        {"name": "plane", "type": f"{svc}.plane_detector:PlaneDetector", "inputs": {"cloud": "cloud.cloud"}},
        {"name": "roi", "type": f"{svc}.roi_filter:RoiFilter", "inputs": {"cloud": "cloud.cloud", "roi": "plane.roi"}},
        {"name": "self", "type": f"{svc}.self_filter:SelfFilter", "params": {"robot": embodiment or robot},
         "inputs": {"cloud": "roi.cloud", "joints": ks.robot(robot, "joints")}},
        {"name": "objects", "type": f"{svc}.cluster_extractor:ClusterExtractor",
         "inputs": {"cloud": "self.cloud", "plane": "plane.plane"}},
    ]
    if contacts:
        modules.append({"name": "range", "type": "range_hypotheses", "params": {"robot": robot},
                        "inputs": {"depth": ks.robot(robot, "depth"), "robot_model": f"{robot}/model.robot_model",
                                   "roi": "plane.roi"}})
    return {"site": site, "node": node or f"vision3d_{robot}", "robot": robot, "clock": clock, "cell": cell,
            "zenoh": zenoh(listen, connect), "modules": modules}


class SiteWatch:
    """A tool session on a site: every module event, each module's last status, and the world clock's progress
    (what ``contactflow echo`` and ``contactflow ls`` show)."""

    FINAL = frozenset({Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.TIMEOUT, Event.HARDWARE_FAILURE})

    def __init__(self, site: str, endpoint: str) -> None:
        from contactflow.nodes.keys import KeySpace
        from contactflow.nodes.transport import ZenohSettings, ZenohTransport

        self.ks = KeySpace(site)
        self.t = ZenohTransport(ZenohSettings(connect=(endpoint,))).open()
        self.events: list[EventMsg] = []
        self.poses: list[ObjectPoses] = []  # the worlds' ground truth (eval/), as it came
        self.progress: list[TaskProgressMsg] = []  # every task module's progress, as it came
        self.contacts: list[ContactEventMsg] = []  # every robot's fused contact events, as they came
        self.status: dict[str, StatusMsg] = {}  # each module's (robot/node/module) last status
        self.first_tick: tuple[float, float] | None = None  # (sim s, wall s) of tick 1
        self.last_tick: tuple[float, float] | None = None
        self._lock = threading.Lock()
        self._subs = [self.t.subscribe(self.ks.events(), self._on_event),
                      self.t.subscribe(self.ks.clock(), self._on_clock),
                      self.t.subscribe(self.ks.evaluation("*", "object_poses"), self._on_poses),
                      self.t.subscribe(self.ks.output("*", "*", "task", "progress"), self._on_progress),
                      self.t.subscribe(self.ks.fused("*", "events"), self._on_contact),
                      self.t.subscribe(self.ks.status(), self._on_status)]

    def _on_status(self, key: str, payload: bytes) -> None:
        msg = decode(payload, StatusMsg, key)
        with self._lock:
            self.status[msg.module] = msg

    def _on_contact(self, key: str, payload: bytes) -> None:
        msg = decode(payload, ContactEventMsg, key)
        with self._lock:
            self.contacts.append(msg)

    def _on_progress(self, key: str, payload: bytes) -> None:
        msg = decode(payload, TaskProgressMsg, key)
        with self._lock:
            self.progress.append(msg)

    def _on_poses(self, key: str, payload: bytes) -> None:
        msg = decode(payload, ObjectPoses, key)
        with self._lock:
            self.poses.append(msg)

    def _on_event(self, key: str, payload: bytes) -> None:
        with self._lock:
            self.events.append(decode(payload, EventMsg, key))

    def _on_clock(self, key: str, payload: bytes) -> None:
        msg = decode(payload, Clock, key)
        now = time.time()  # epoch, as the events' t_wall stamps of the nodes on this machine
        with self._lock:
            if msg.tick >= 1 and self.first_tick is None:
                self.first_tick = (msg.t, now)
            self.last_tick = (msg.t, now)

    def outcome(self, module: str) -> EventMsg | None:
        """The final event of the module whose address ends with ``module``, if it came."""
        with self._lock:
            return next((e for e in self.events if e.module.endswith(module) and e.event in self.FINAL), None)

    def task_progress(self) -> list[TaskProgressMsg]:
        """Every task progress report so far."""
        with self._lock:
            return list(self.progress)

    def contact_events(self) -> list[ContactEventMsg]:
        """Every fused contact event so far."""
        with self._lock:
            return list(self.contacts)

    def object_poses(self) -> list[ObjectPoses]:
        """Every ground-truth message so far."""
        with self._lock:
            return list(self.poses)

    def statuses(self) -> dict[str, StatusMsg]:
        """Each module's last status so far."""
        with self._lock:
            return dict(self.status)

    def messages(self) -> list[EventMsg]:
        """Every event so far, as it came."""
        with self._lock:
            return list(self.events)

    def sequence(self) -> list[tuple[float, str, str]]:
        """(sim time, module, event) of every event, in simulated-time order."""
        with self._lock:
            return sorted((round(e.hdr.t_sim, 6), e.module.rsplit("/", 1)[-1], str(e.event)) for e in self.events)

    def close(self) -> None:
        for s in self._subs:
            s.close()
        self.t.close()


@dataclass
class CellRun:
    """What a run of a cell's nodes gave: each robot's task outcome, every event, the clock's pace."""

    outcomes: dict[str, EventMsg]
    events: list[tuple[float, str, str]]
    sim_s: float  # simulated s from tick 1 to the last outcome
    wall_s: float  # wall s over the same span
    messages: list[EventMsg]  # every event as it came, with its detail and values
    poses: list[ObjectPoses]  # the world's ground truth object poses (eval/), as they came
    contacts: list[ContactEventMsg]  # the robots' fused contact events, as they came
    statuses: dict[str, StatusMsg]  # each module's last status (robot/node/module -> status), at the end
    t0_wall: float  # wall s (epoch) of tick 1: what a status's wall stamp counts its ticks from
    control_rate: float  # Hz, the world's ticks per simulated s

    @property
    def rtf(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else 0.0

    def cpu_per_tick(self) -> dict[str, float]:
        """Each module's CPU time per world tick (ms), from tick 1 to its last status, most first: where a lockstep
        tick goes. The ticks up to a status come from its wall stamp at the run's pace (the world's own statuses carry no simulated time: its node keeps the wall clock)."""
        out = {}
        for name, s in self.statuses.items():
            ticks = (s.hdr.t_wall - self.t0_wall) * self.rtf * self.control_rate
            if ticks >= 1.0:
                out[name] = 1e3 * s.cpu_s / ticks
        return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def start_nodes(folder: Path, configs: list[Mapping[str, Any]], site: str, endpoint: str,
                processes: bool = False, timeout: float = 60.0,
                joined: Callable[[], None] | None = None) -> tuple[list[Any], SiteWatch]:
    """Start node ``configs`` in order (the world first: a site watch joins it on ``endpoint``); each a
    process of its own with ``processes``, else a zenoh session each in this process.

    Each node is started once the watch sees the one before it: a node that joined before the
    watch had reached the world would not know of the watch's subscriptions, and its first
    events (a task's first steps) would reach nobody. ``joined`` is called once the world is up,
    before the next node starts: another session that must hear every node (a predictor's watch)
    opens there, for the same reason.
    """
    from contactflow.nodes.config import load_node_config
    from contactflow.nodes.keys import ANY
    from contactflow.nodes.node import Node
    from contactflow.nodes.procs import spawn_node, wait_for, write_config

    folder.mkdir(parents=True, exist_ok=True)
    started: list[Any] = []
    watch: SiteWatch | None = None
    try:
        for cfg in configs:
            path = write_config(folder / f"{cfg['node']}.yaml", cfg)
            if processes:
                started.append(spawn_node(path, folder / f"{path.stem}.log"))
            else:
                node = Node(load_node_config(path))
                node.start()
                started.append(node)
            if watch is None:
                watch = SiteWatch(site, endpoint)
            up = watch.ks.alive_module(ANY, cfg["node"], ANY)
            if not wait_for(lambda up=up, w=watch: bool(w.t.alive(up, timeout=0.5)), timeout):
                raise TimeoutError(f"node {cfg['node']!r} did not come up within {timeout:g} s (see {folder})")
            if joined is not None and len(started) == 1:
                joined()
    except BaseException:
        stop_nodes(started, watch, processes)
        raise
    assert watch is not None
    return started, watch


def stop_nodes(started: list[Any], watch: SiteWatch | None, processes: bool = False) -> None:
    """Stop what :func:`start_nodes` started, the world first (it would hold robots whose control nodes stopped before it)."""
    from contactflow.nodes.procs import stop_process

    for s in started:
        if processes:
            stop_process(s)
        else:
            s.stop()
    if watch is not None:
        watch.close()


def _control_rate(world: Mapping[str, Any]) -> float:
    """Hz, the ticks per simulated s of the world node's ``world`` module (:func:`world_node`), its default if unset."""
    from contactflow.embodiments.modules.world_module import WorldModule

    (module,) = (m for m in world["modules"] if m["type"] == "world")
    return float(module.get("params", {}).get("control_rate", WorldModule.Params.control_rate))


def run_cell(folder: Path, world: Mapping[str, Any], controls: list[Mapping[str, Any]], endpoint: str,
             processes: bool = False, timeout: float = 300.0, keep: Callable[[Any], None] | None = None,
             services: tuple[Mapping[str, Any], ...] = (), after: float = 0.0,
             joined: Callable[[], None] | None = None) -> CellRun:
    """Run a world node and control nodes until every control node's task ended.

    ``processes``: each node a process of its own (``contactflow node``); else all of them in
    this process, a zenoh session each. ``keep`` is called with the world module (in-process
    runs) before the nodes stop, to read what only the simulation knows. ``services`` are
    nodes the control nodes read (a vision node), started before them. The nodes run on for ``after`` s
    of wall time once the last task ended (what a predictor was still deciding gets said). ``joined``:
    as :func:`start_nodes`.
    """
    from contactflow.nodes.procs import wait_for

    configs = [world, *services, *controls]
    robots = [next(m["robot"] for m in c["modules"] if m["name"] == "task") for c in controls]
    names = [f"{r}/{c['node']}/task" for r, c in zip(robots, controls, strict=True)]
    started, watch = start_nodes(folder, configs, world["site"], endpoint, processes, joined=joined)
    try:
        if not wait_for(lambda: all(watch.outcome(n) for n in names), timeout):
            logs = "".join((folder / f"{c['node']}.log").read_text()[-2000:] for c in configs
                           if (folder / f"{c['node']}.log").exists())
            raise TimeoutError(f"tasks still running after {timeout:g} s: {watch.sequence()[-10:]} {logs}")
        time.sleep(after)
        outcomes = {r: watch.outcome(n) for r, n in zip(robots, names, strict=True)}
        end = max(outcomes.values(), key=lambda e: e.hdr.t_sim)
        t0_sim, t0_wall = watch.first_tick
        if keep is not None and not processes:
            keep(started[0].host.modules[("site", "world")].module)
        return CellRun(outcomes, watch.sequence(), end.hdr.t_sim - t0_sim, end.hdr.t_wall - t0_wall, watch.messages(),
                       watch.object_poses(), watch.contact_events(), watch.statuses(), t0_wall,
                       _control_rate(world))
    finally:
        stop_nodes(started, watch, processes)


def write_cell(path: Path, robot: str | list[Mapping[str, Any]], objects: list, bottles: list = (),
               cameras: list = ()) -> Path:
    """A scene file at ``path``: ``robot`` at its own placement (or the scene file's robot entries), the table,
    ``objects`` (ObjectSpecs), ``bottles`` (ScrewBottleSpecs) and fixed ``cameras`` (CameraPlacements)."""
    import dataclasses

    from contactflow.embodiments.scene_file import bottle_entry, object_entry

    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"scene": "table", "robots": [{"name": robot}] if isinstance(robot, str) else _plain(robot),
           "objects": [object_entry(o) for o in objects] + [bottle_entry(b) for b in bottles]}
    if cameras:
        doc["cameras"] = [_plain(dataclasses.asdict(c)) for c in cameras]
    path.write_text(yaml.safe_dump(doc))
    return path


class CellSession:
    """One robot's cell on the runtime, in this process: a world node (the table and ``objects``) and the
    robot's control node running ``task``, each a zenoh session, in lockstep; watched as a supervisor
    watches a robot: the task's progress, the world's ground truth on ``eval/`` and its outcome.

    Use as a context manager; leaving it stops the nodes, the world first (it would hold the robot
    of a control node stopped before it).
    """

    def __init__(self, folder: Path, objects: list, robot: str, task_file: str | Path, task: str,
                 plan: Mapping[str, Any], seed: int = 0, ground_truth_hz: float = 4.0, contacts: bool = False) -> None:
        self.folder = Path(folder)
        self.contacts = contacts  # the control node runs the robot's contact fusion (contact_modules)
        self.robot, self.objects = robot, list(objects)
        self.task_file, self.task, self.plan = task_file, task, dict(plan)
        self.seed, self.ground_truth_hz = seed, ground_truth_hz
        self._nodes: list[Any] = []
        self.watch: SiteWatch | None = None

    def __enter__(self) -> CellSession:
        from contactflow.nodes.procs import free_port

        cell = write_cell(self.folder / "cell.yaml", self.robot, self.objects)
        endpoint, site = f"tcp/127.0.0.1:{free_port()}", f"cell{free_port()}"
        control = control_node(site, self.robot, self.robot, self.task_file, self.task, self.plan,
                               connect=(endpoint,), autostart=True, contacts=self.contacts)
        world = world_node(site, cell, listen=endpoint, wait_for=(control["node"],), seed=self.seed,
                           ground_truth_hz=self.ground_truth_hz)
        self._nodes, self.watch = start_nodes(self.folder, [world, control], site, endpoint)
        self._task = f"{control['node']}/task"
        return self

    def __exit__(self, *exc: object) -> None:
        stop_nodes(self._nodes, self.watch)
        self._nodes, self.watch = [], None

    def progress(self) -> list[TaskProgressMsg]:
        """The task's progress reports so far (stamped with simulated time)."""
        assert self.watch is not None
        return self.watch.task_progress()

    def poses(self) -> list[ObjectPoses]:
        """The world's ground-truth messages so far."""
        assert self.watch is not None
        return self.watch.object_poses()

    def outcome(self) -> EventMsg | None:
        """The task's final event, once it ended."""
        assert self.watch is not None
        return self.watch.outcome(self._task)


PLACE_TARGET = (0.55, -0.12, 0.93)  # m, where tombatossals' pick and place puts the can (grasp frame)
TAP_ABOVE = (0.85, 0.3, 0.95)  # m, where melfa taps down onto the cube of the shared table


def _pose(xyz: tuple[float, float, float]) -> list[float]:
    from contactflow.embodiments.primitives.base import pose6, top_grasp_pose

    p = pose6(top_grasp_pose(xyz))
    return [p[k] for k in ("x", "y", "z", "roll", "pitch", "yaw")]


def table_cell(site: str, endpoint: str, melfa: bool = False, predictor: Mapping[str, Any] | None = None,
               task: str = "pick_and_place", cell_map: bool = False, pipeline: bool = False) -> tuple[dict, list[dict]]:
    """The runtime's reference cell: tombatossals picks the can and places it (thesis Fig. 6.3, ``task`` of
    ``thesis.yaml``: ``careful_pick_and_place`` corrects what its predictor reports), its grasp watched on its
    fused contacts while it carries the can (and by its predictor, with ``predictor``: its params); with
    ``melfa`` the cell is the shared table and melfa, across it, taps down onto a cube; with ``cell_map`` too, melfa
    runs its contact fusion as well (its touch stops on its fused contacts), tombatossals' control node the
    cell's map of both (:func:`cell_map_module`), and tombatossals' carry watcher reads its grasp from that map
    (the robot subscribes to its cell's contacts). With ``pipeline`` the world steps a tick while its nodes step the one
    before (the world module's ``pipeline``).

    Returns the world node (listening on ``endpoint``, waiting for the control nodes before
    tick 1, so a run repeats exactly) and the control nodes (connecting to it, tasks autostarted).
    """
    from contactflow.embodiments.tasks import TASKS_DIR
    from contactflow.nodes.keys import KeySpace

    cell = "shared_table" if melfa else "pick_place"
    watcher = {"wait_event": {"contacts": KeySpace(site).fused(cell, "contacts")}} if melfa and cell_map else None
    # the full stack of a control node: its contact fusion too, which watches the grasp while the can is carried
    controls = [control_node(site, "tombatossals", "tombatossals", TASKS_DIR / "thesis.yaml", task,
                             {"target": _pose(PLACE_TARGET), "sensor": "fused"}, connect=(endpoint,), autostart=True,
                             contacts=True, predictor=predictor, inputs=watcher)]
    if melfa:
        tap = {"above": _pose(TAP_ABOVE), "sensor": "fused" if cell_map else "own"}
        controls.append(control_node(site, "melfa", "melfa", TASKS_DIR / "tap.yaml", "tap", tap,
                                     connect=(endpoint,), autostart=True, contacts=cell_map))
        if cell_map:
            controls[0]["modules"].append(cell_map_module(cell, ("tombatossals", "melfa")))
    w = world_node(site, CELLS / f"{cell}.yaml", listen=endpoint, wait_for=tuple(c["node"] for c in controls),
                   pipeline=pipeline)
    return w, controls


def vision_cell(site: str, endpoint: str, camera_hz: float = 2.0, contacts: bool = False) -> tuple[dict, dict, dict]:
    """The reference cell with the 3D vision computer: tombatossals picks the can its vision3d node segmented from
    the world's Kinect stream (``camera_hz``, in simulated time) and places it (``pick_and_place``); with
    ``contacts`` the control node runs the robot's contact fusion and the vision node the range generator it fuses
    (:func:`vision_node`). Returns the world node (listening on ``endpoint``, waiting for both nodes before tick 1),
    the control node and the vision node (connecting to it)."""
    from contactflow.embodiments.tasks import TASKS_DIR

    control = control_node(site, "tombatossals", "tombatossals", TASKS_DIR / "thesis.yaml", "pick_and_place",
                           {"target": _pose(PLACE_TARGET)}, connect=(endpoint,), autostart=True, inputs=VISION_INPUTS,
                           contacts=contacts)
    vision = vision_node(site, "tombatossals", connect=(endpoint,), contacts=contacts)
    world = world_node(site, CELLS / "pick_place.yaml", listen=endpoint, wait_for=(control["node"], vision["node"]),
                       camera_hz=camera_hz)
    return world, control, vision
