"""The module host: wires modules to a transport, schedules their loops, answers control.

One host runs inside each node process. It gives every module a :class:`HostedIO` (inputs
decoded and validated, outputs stamped with provenance), steps running modules at their
rate on the node's clock, publishes status, announces modules with liveliness tokens,
arbitrates shared resources (thesis §6.6), counts sequence gaps per input and never lets a
module's exception or a malformed message take the node down.
"""

from __future__ import annotations

import functools
import itertools
import logging
import math
import threading
import time
import traceback
import weakref
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any, Protocol

from contactflow.nodes.acl import AccessDenied
from contactflow.nodes.clock import LockstepClock, SimClock, WallClock
from contactflow.nodes.config import ModuleConfig, NodeConfig, mix_problem
from contactflow.nodes.keys import KeyExprError, KeySpace, ModuleAddr
from contactflow.nodes.messages import (
    Command,
    ControlReply,
    ControlRequest,
    EventMsg,
    Mark,
    ParamValue,
    StatusMsg,
)
from contactflow.nodes.module import Layer, LayerError, Module
from contactflow.nodes.params import ParamError, params_dict
from contactflow.nodes.status import STATUS_EVENT, Event, Status
from contactflow.nodes.transport import Handle, Transport, key_matches
from contactflow.nodes.wire import Header, Message, MsgId, WireError, decode, encode, stamp

STATUS_PERIOD = 1.0  # s between periodic status messages


class TickHook(Protocol):
    """Work a node runs after each tick's modules (:meth:`ModuleHost.attach`)."""

    rate_hz: float  # Hz at which it wants to run while active

    def after_tick(self) -> None: ...

    def active(self) -> bool: ...


STEP_ORDER = {Layer.INTERFACE: 0, Layer.SERVICE: 1, Layer.PRIMITIVE: 2, Layer.TASK: 3}
"""A tick steps the layers bottom-up, as data flows (§6.1): a task sees what its primitives did in the tick,
and a primitive it starts takes its first step at the next tick, on this node as on any other."""
QUEUE_DEPTH = 256  # messages kept per input port between two steps
MAX_SOURCES = 1024  # sources tracked per input port; bounds memory against hostile senders
MAX_SEQ_JUMP = 1 << 24  # a sequence number this far ahead is a new numbering (a forged or reset source), not loss
MARK_WAIT = 5.0  # s of wall time a lockstep node waits for the messages a tick's marks name before it steps
WORK_BEAT = 1.0  # s of wall time between a lockstep node's "still working" notes while one tick's step lasts
SLOW_STEP = 1.0  # s of wall time a module's step may take before the node logs it
MAX_MARK_LEAD = 64
"""Messages of one stream a mark may name beyond the last one heard: a tick leaves a few in flight, so a
mark further ahead is forged (or predates the node) and is not waited for, else one hostile ack would
hold every node subscribed to the stream for MARK_WAIT."""


@dataclass
class Counters:
    received: int = 0
    rejected: int = 0
    published: int = 0
    steps: int = 0
    cpu: float = 0.0  # s of CPU time its steps took (the stepping thread's: waits cost none)
    errors: int = 0
    gaps: dict[str, int] = field(default_factory=dict)  # input port -> sequence numbers never received
    dropped: dict[str, int] = field(default_factory=dict)  # input port -> messages pushed out of its full queue


class SeqTracker:
    """Follows the sequence number of every source on one input; a jump forward is a gap.

    A number at or below 1 after a higher one is a restart of the source (a new process),
    any other number not above the last is a duplicate; neither is loss. Seq 0 marks a
    message nobody numbered (a hand-written client), which cannot reveal a gap.
    """

    def __init__(self, max_sources: int = MAX_SOURCES) -> None:
        self.last: dict[str, int] = {}  # oldest-heard source first
        self.max_sources = max_sources

    def observe(self, hdr: Header) -> int:
        """Record ``hdr``; the count of sequence numbers it shows were missed."""
        if hdr.seq == 0:
            return 0
        prev = self.last.pop(hdr.source, None)
        if prev is None:
            if len(self.last) >= self.max_sources:
                self.last.pop(next(iter(self.last)))  # forget the longest-silent source
            self.last[hdr.source] = hdr.seq
            return 0
        restart = hdr.seq <= 1 < prev
        self.last[hdr.source] = hdr.seq if hdr.seq > prev or restart else prev
        return hdr.seq - prev - 1 if prev < hdr.seq <= prev + MAX_SEQ_JUMP else 0


class HostedIO:
    """ModuleIO of one hosted module."""

    def __init__(self, host: ModuleHost, hm: HostedModule) -> None:
        self._host = host
        self._hm = hm
        self._lock = threading.Lock()
        self._latest: dict[str, Message] = {}
        self._queues: dict[str, deque[Message]] = {p.name: deque() for p in hm.module.inputs}
        self._trackers: dict[str, SeqTracker] = {p.name: SeqTracker() for p in hm.module.inputs}
        self._seqs: dict[str, int] = {}  # one counter per stream, so a gap on a stream means loss
        self._held: list[tuple[str, Message]] = []  # lockstep: messages sent during the tick being stepped, for the next
        self.emitted: set[Event] = set()  # the events the module raised itself since its last RUN
        hm.counters.gaps = {p.name: 0 for p in hm.module.inputs}
        hm.counters.dropped = {p.name: 0 for p in hm.module.inputs}

    @property
    def now(self) -> float:
        return self._host.clock.now()

    @property
    def transport(self) -> Transport:
        """The node's transport, for infrastructure modules (broker, robot agent) only."""
        return self._host.transport

    @property
    def keyspace(self) -> KeySpace:
        return self._host.ks

    @property
    def node(self) -> str:
        return self._host.config.node

    @property
    def robot(self) -> str:
        """The robot the module belongs to (``site`` for none)."""
        return self._hm.addr.robot

    def deliver(self, port: str, msg: Message) -> int:
        """Queue an input; returns how many sequence numbers of its source were missed before it.

        In lockstep a message another node sent during the tick this node steps (it travelled
        fast) waits for the next tick (with a pipelined world, the one after), as one that
        travelled slowly does: see :meth:`release`.
        """
        with self._lock:
            missed = self._trackers[port].observe(msg.hdr)
            if missed:
                self._hm.counters.gaps[port] += missed
            if 0 <= self._host.tick_no <= msg.hdr.tick + self._host.lag:
                self._held.append((port, msg))
            else:
                self._latest[port] = msg
                self._enqueue(port, msg)
        self._host.delivered()
        return missed

    def release(self, tick: int) -> None:
        """Make the held messages sent before ``tick`` inputs (the host calls it before stepping ``tick``)."""
        with self._lock:
            held, self._held = self._held, []
            for port, msg in held:
                if msg.hdr.tick < tick:
                    self._latest[port] = msg
                    self._enqueue(port, msg)
                else:
                    self._held.append((port, msg))

    def _enqueue(self, port: str, msg: Message) -> None:
        """Queue ``msg`` (the lock held); on a full queue the oldest message of the source with the most queued
        goes, so a source that floods a port pushes out its own messages, never a quieter source's."""
        q = self._queues[port]
        if len(q) >= QUEUE_DEPTH:
            counts = Counter(m.hdr.source for m in q)
            top = max(counts, key=counts.__getitem__)
            del q[next(i for i, m in enumerate(q) if m.hdr.source == top)]
            self._hm.counters.dropped[port] += 1
        q.append(msg)

    def heard(self, port: str, source: str) -> int:
        """The highest sequence number of ``source`` delivered on ``port`` (0: none)."""
        with self._lock:
            return self._trackers[port].last.get(source, 0)

    def latest(self, port: str) -> Message | None:
        with self._lock:
            return self._latest.get(port)

    def take(self, port: str) -> list[Message]:
        with self._lock:
            q = self._queues.get(port)
            if not q:
                return []
            out = list(q)
            q.clear()
            return out

    def wired(self, port: str) -> bool:
        return port in self._hm.wired

    def next_seq(self, stream: str) -> int:
        n = self._seqs.get(stream, 0) + 1
        self._seqs[stream] = n
        return n

    def publish(self, port: str, msg: Message, inputs: list[MsgId] | None = None) -> None:
        pub = self._hm.publishers.get(port)
        if pub is None:
            raise LayerError(f"{self._hm.addr}: no output port {port!r}")
        if inputs is None:
            with self._lock:
                inputs = [m.hdr.id for m in self._latest.values()]
        weight = self._hm.weights.get(port)
        if weight is not None:  # the configuration mixes the resource this port commands
            msg.weight = weight
        stamp(msg, f"{self._hm.addr}/{port}", self.next_seq(port), self.now, inputs)
        msg.hdr.tick = self._host.tick_no
        pub(encode(msg))
        self._hm.counters.published += 1
        self._host.mark(self._hm.out_keys[port], msg.hdr.source, msg.hdr.seq)

    def emit(self, event: Event, detail: str = "", values: dict[str, float] | None = None) -> None:
        self.emitted.add(event)
        msg = EventMsg(event=event, module=str(self._hm.addr), detail=detail, values=values or {})
        stamp(msg, str(self._hm.addr), self.next_seq("/evt"), self.now)
        self._hm.event_pub(encode(msg))

    def command(self, target: str, cmd: Command, params: dict[str, ParamValue] | None = None) -> ControlReply:
        if not self._hm.module.may_command:
            raise LayerError(f"{self._hm.addr}: a {self._hm.module.layer} module may not send control messages")
        return self._host.send_control(target, cmd, params or {}, issuer=str(self._hm.addr), default_robot=self._hm.addr.robot)

    def log(self, text: str) -> None:
        self._host.log.info("%s: %s", self._hm.addr, text)

    def wake(self) -> None:
        self._host.wake(self._hm)

    def attach(self, key: str, hook: TickHook) -> None:
        """Run ``hook`` after every tick of the node (infrastructure: a robot's arm controllers)."""
        self._host.attach(key, hook)


@dataclass
class HostedModule:
    cfg: ModuleConfig
    module: Module
    addr: ModuleAddr
    io: HostedIO | None = None
    publishers: dict[str, Any] = field(default_factory=dict)
    out_keys: dict[str, str] = field(default_factory=dict)  # output port -> key it publishes on
    in_keys: dict[str, str] = field(default_factory=dict)  # wired input port -> key expression it subscribes to
    event_pub: Any = None
    status_pub: Any = None
    handles: list[Handle] = field(default_factory=list)
    claims: list[Handle] = field(default_factory=list)
    claimed: dict[str, str] = field(default_factory=dict)  # resource -> claim mode (excl | mix)
    weights: dict[str, float] = field(default_factory=dict)  # output port -> mixing weight
    wired: set[str] = field(default_factory=set)  # input ports subscribed to a source
    counters: Counters = field(default_factory=Counters)
    next_due: float = 0.0
    woken: bool = False  # step at the next tick, whatever the period (work arrived off the step loop)
    last_status: float = -1e9
    detail: str = ""
    lock: threading.RLock = field(default_factory=threading.RLock)

    @property
    def state(self) -> Status:
        return self.module.state


_hosts: weakref.WeakKeyDictionary[Any, weakref.ref[ModuleHost]] = weakref.WeakKeyDictionary()  # weak both ways


def tick_of(transport: Transport) -> int:
    """The world tick the node on ``transport`` steps (-1: none, or not in lockstep): what a robot's state
    and commands go by where the node's modules share them outside their ports (a robot link)."""
    ref = _hosts.get(transport)
    host = ref() if ref is not None else None
    return -1 if host is None else host.tick_no


class ModuleHost:
    """Hosts the modules of one node on a transport."""

    def __init__(self, config: NodeConfig, transport: Transport, clock: WallClock | SimClock | None = None) -> None:
        self.config = config
        self.ks: KeySpace = config.keyspace
        self.transport = transport
        _hosts[transport] = weakref.ref(self)
        if clock is None and config.clock == "lockstep":
            clock = LockstepClock(transport, self.ks, config.node, config.cell)
        elif clock is None and config.clock == "sim":
            clock = SimClock(transport, self.ks, config.cell)
        self.clock = clock or WallClock()
        self.log = logging.getLogger(f"contactflow.node.{config.node}")
        self.modules: dict[tuple[str, str], HostedModule] = {}
        self._order: list[HostedModule] = []  # the modules in STEP_ORDER, kept as modules come and go
        self._hooks: dict[str, TickHook] = {}  # run after each tick's modules; replaced, never changed
        self._lock = threading.RLock()
        self._claim_lock = threading.RLock()  # claims of this node are checked, taken and released one at a time
        self._stop = threading.Event()
        self._wake = threading.Event()  # ends a wall-clock node's wait for its next due module
        self._ack_lock = threading.Lock()
        self._acked: tuple[int, bool] | None = None  # lockstep: the last tick acked, and whether the node was busy
        self._stepping: tuple[int, float] | None = None  # lockstep: the tick being stepped, and when it was last told
        self._thread: threading.Thread | None = None
        self._node_token: Handle | None = None
        self._marks: dict[tuple[str, str], int] = {}  # (key, source) -> last seq published this tick (lockstep)
        self._delivery = threading.Condition()
        self.mark_timeouts = 0  # ticks stepped without every message their marks named
        self.marks_refused = 0  # marks too far ahead of their stream to be waited for (MAX_MARK_LEAD)
        self.tick_no = -1  # the world tick a lockstep node steps (-1: not in lockstep)
        self.lag = 0  # ticks beyond the next that another node's message of a tick waits to be an input (the world's)
        self._ticked = False  # the node stepped its modules once
        self.dead = threading.Event()  # the loop died (the node is down, its process should exit non-zero)
        self._ctl_seqs: dict[str, itertools.count] = {}  # issuer -> sequence of its control requests

    # -- set up ---------------------------------------------------------------------------
    def add(self, cfg: ModuleConfig, module: Module | None = None) -> HostedModule:
        module = module if module is not None else cfg.cls(cfg.name, cfg.params)
        addr = ModuleAddr(cfg.robot, self.config.node, cfg.name)
        for res in cfg.mix:
            problem = mix_problem(type(module), res)
            if problem:
                raise LayerError(f"{addr}: mix: {res}: {problem}")
        hm = HostedModule(cfg=cfg, module=module, addr=addr,
                          weights={p.name: cfg.mix[p.resource] for p in module.outputs if p.resource in cfg.mix})
        hm.io = HostedIO(self, hm)
        t = self.transport
        out_keys = module.default_output_keys(self.ks, addr.robot, addr.module, module.params)
        for port in module.outputs:
            key = (cfg.outputs.get(port.name) or out_keys.get(port.name)
                   or self.ks.output(addr.robot, addr.node, addr.module, port.name))
            hm.publishers[port.name] = t.publisher(key)
            hm.out_keys[port.name] = key
        hm.event_pub = t.publisher(self.ks.events(*self._a(addr)))
        hm.status_pub = t.publisher(self.ks.status(*self._a(addr)))
        in_keys = module.default_input_keys(self.ks, addr.robot, addr.module, module.params)
        for port in module.inputs:
            src = cfg.inputs.get(port.name)
            key = src.keyexpr(self.ks, addr.robot) if src is not None else in_keys.get(port.name)
            if key is None:
                continue
            hm.handles.append(t.subscribe(key, self._input_callback(hm, port.name, port.type)))
            hm.wired.add(port.name)
            hm.in_keys[port.name] = key
        hm.handles.append(t.queryable(self.ks.control(*self._a(addr)), self._control_callback(hm)))
        module.setup(hm.io)
        # presence once set up: a module seen alive is ready (a world has built its scene, a planner its model)
        hm.handles.append(t.token(self.ks.alive_module(*self._a(addr))))
        with self._lock:
            self.modules[(addr.robot, addr.module)] = hm
            self._order = sorted(self.modules.values(), key=lambda h: STEP_ORDER[h.module.layer])
        return hm

    @staticmethod
    def _a(addr: ModuleAddr) -> tuple[str, str, str]:
        return addr.robot, addr.node, addr.module

    def _input_callback(self, hm: HostedModule, port: str, type_: type[Message]):
        def on_sample(key: str, payload: bytes) -> None:
            hm.counters.received += 1
            try:
                msg = decode(payload, type_, key)
            except WireError as exc:
                self._rejected(hm, "input", exc)
                return
            missed = hm.io.deliver(port, msg)
            if missed:
                total = hm.counters.gaps[port]
                if total - missed < 10 or total // 1000 != (total - missed) // 1000:
                    self.log.warning("%s.%s: %d message(s) of %s missed before seq %d (%d missed on this input)",
                                     hm.addr, port, missed, msg.hdr.source, msg.hdr.seq, total)
        return on_sample

    def _control_callback(self, hm: HostedModule):
        def on_query(key: str, payload: bytes) -> bytes:
            try:
                req = decode(payload, ControlRequest, key)
            except WireError as exc:
                self._rejected(hm, "control request", exc)
                return encode(self._reply(hm, ControlReply(ok=False, error=str(exc), state=hm.state), None))
            return encode(self._reply(hm, self.handle_control(hm, req), req))
        return on_query

    def _reply(self, hm: HostedModule, reply: ControlReply, req: ControlRequest | None) -> ControlReply:
        """The module's header on its answer: its path, a seq of its own, the node's clock, the request it answers."""
        return stamp(reply, f"{hm.addr}/ctl", hm.io.next_seq("/ctl"), self.clock.now(),
                     [req.hdr.id] if req is not None and req.hdr.source else [])

    def _rejected(self, hm: HostedModule, what: str, exc: Exception) -> None:
        """Count a message that did not decode; log the first ten and every thousandth (a flood is no log flood)."""
        hm.counters.rejected += 1
        if hm.counters.rejected <= 10 or hm.counters.rejected % 1000 == 0:
            self.log.warning("rejected %s #%d of %s: %s", what, hm.counters.rejected, hm.addr, exc)

    # -- control --------------------------------------------------------------------------
    def handle_control(self, hm: HostedModule, req: ControlRequest) -> ControlReply:
        with hm.lock:
            try:
                return self._apply(hm, req)
            except Exception as exc:  # a module hook raised: report, never crash the node
                self._fail(hm, f"{req.cmd} raised {type(exc).__name__}: {exc}")
                return ControlReply(ok=False, error=hm.detail, state=hm.state)

    def _apply(self, hm: HostedModule, req: ControlRequest) -> ControlReply:
        m = hm.module
        if req.cmd == Command.RUN:
            old = m.params
            if req.params:  # first: the parameters may choose what the run commands (a primitive's arm)
                m.set_params(dict(req.params))
            refusal = self._claim(hm)
            if refusal:
                m.params = old
                return ControlReply(ok=False, error=refusal, state=m.state)
            if hm.io is not None:
                hm.io.emitted.clear()
            m.start()
            m.state = Status.RUNNING
            hm.detail = ""
            # due now, its period counted from now; before the node's first tick, from that tick: the clock's
            # reading is no tick's time then (a lockstep node autostarted before the world's first clock reached
            # it read 0, not the first tick's 0.4 s, and its 1 Hz plane detector fitted at 1.0 s, not 1.4 s,
            # so a seeded run with the vision node detected at another time in another process layout)
            hm.next_due = self.clock.now() if self._ticked else -math.inf
            self._resume()
        elif req.cmd == Command.STOP:
            if m.state == Status.RUNNING:
                m.stop()
            m.state = Status.STOPPED
            self._release(hm)
        elif req.cmd == Command.RESET:
            if isinstance(hm.cfg.params, type(m).Params):  # back to the configured parameters
                m.params = hm.cfg.params
            m.reset()
            if m.state != Status.RUNNING:
                m.state = Status.IDLE
        elif req.cmd == Command.SET:
            try:
                m.set_params(dict(req.params))
            except ParamError as exc:
                return ControlReply(ok=False, error=str(exc), state=m.state, params=params_dict(m.params))
        elif req.cmd == Command.DESCRIBE:
            return ControlReply(ok=True, state=m.state, params=params_dict(m.params), description=m.describe_yaml())
        self._publish_status(hm)
        return ControlReply(ok=True, state=m.state, params=params_dict(m.params))

    def _claim(self, hm: HostedModule) -> str:
        """Claim the module's resources; a refusal message when another module holds one.

        Claims of this node are taken under one lock, so two local modules never both pass
        the check. Across nodes a claim is announced first and checked after: two nodes
        claiming at the same moment see each other and both refuse, neither commands twice.
        """
        if hm.claims:
            return ""
        try:
            resources = hm.module.claimed_resources()
        except Exception as exc:  # e.g. the robot the module would command does not answer
            return f"{hm.addr}: cannot tell which resources it commands: {exc}"
        if not resources:
            return ""
        a = hm.addr
        with self._claim_lock:
            for res in resources:
                refusal = self._conflict(hm, res, self._local_holders(hm, res))
                if refusal:
                    return refusal
            for res in resources:
                mode = "mix" if res in hm.cfg.mix else "excl"
                hm.claims.append(self.transport.token(self.ks.claim(a.robot, res, a.node, a.module, mode)))
                hm.claimed[res] = mode
            for res in resources:
                refusal = self._conflict(hm, res, self._remote_holders(hm, res))
                if refusal:
                    self._release(hm)
                    return refusal
        return ""

    def _local_holders(self, hm: HostedModule, res: str) -> list[tuple[str, str, str]]:
        with self._lock:
            others = [o for o in self.modules.values() if o is not hm and o.addr.robot == hm.addr.robot]
        with self._claim_lock:
            return [(o.addr.node, o.addr.module, o.claimed[res]) for o in others if res in o.claimed]

    def _remote_holders(self, hm: HostedModule, res: str) -> list[tuple[str, str, str]]:
        holders = []
        for key in self.transport.alive(self.ks.claim(hm.addr.robot, res), timeout=0.5):
            try:
                node, module, mode = self.ks.parse_claim(key)
            except KeyExprError:
                self.log.warning("%s: ignoring malformed claim token %s", hm.addr, key)
                continue
            if (node, module) != (hm.addr.node, hm.addr.module):
                holders.append((node, module, mode))
        return holders

    @staticmethod
    def _conflict(hm: HostedModule, res: str, holders: list[tuple[str, str, str]]) -> str:
        """The refusal when ``hm`` may not command ``res`` next to ``holders``; "" when it may."""
        if not holders:
            return ""
        exclusive = [h for h in holders if h[2] != "mix"]
        if res in hm.cfg.mix and not exclusive:
            return ""
        node, module, _ = (exclusive or holders)[0]
        why = (f"{node}/{module} does not declare weighted mixing of it" if res in hm.cfg.mix
               else f"{hm.addr.module} does not declare weighted mixing of it")
        return (f"resource {res!r} of robot {hm.addr.robot!r} is already commanded by {node}/{module} "
                f"and {why}; stop {node}/{module} first, or declare weighted mixing "
                f"(mix: {{{res}: <weight>}}) for every module commanding it in the configuration")

    def _release(self, hm: HostedModule) -> None:
        with self._claim_lock:
            for c in hm.claims:
                c.close()
            hm.claims.clear()
            hm.claimed.clear()

    def send_control(self, target: str, cmd: Command, params: dict[str, ParamValue], issuer: str = "",
                     default_robot: str = "site", timeout: float = 3.0) -> ControlReply:
        robot, _, module = target.rpartition("/")
        robot = robot or default_robot
        req = ControlRequest(cmd=cmd, params=params, issuer=issuer)
        source = f"{issuer or f'site/{self.config.node}/host'}/ctl"
        stamp(req, source, next(self._ctl_seqs.setdefault(source, itertools.count(1))), self.clock.now())
        local = self.modules.get((robot, module))
        if local is not None:
            return self.handle_control(local, decode(encode(req), ControlRequest))
        key = self.ks.control(robot, "*", module)
        try:
            replies = self.transport.query(key, encode(req), timeout=timeout)
        except AccessDenied as exc:
            return ControlReply(ok=False, error=str(exc), state=Status.ERROR)
        if not replies:
            return ControlReply(ok=False, error=f"no module answers on {key}", state=Status.ERROR)
        rkey, payload = replies[0]
        try:
            return decode(payload, ControlReply, rkey)
        except WireError as exc:
            return ControlReply(ok=False, error=str(exc), state=Status.ERROR)

    # -- running ----------------------------------------------------------------------------
    def _publish_status(self, hm: HostedModule) -> None:
        m = hm.module
        msg = StatusMsg(module=str(hm.addr), layer=str(m.layer), state=m.state, rate_hz=m.params.rate_hz,
                        steps=hm.counters.steps, cpu_s=hm.counters.cpu, rejected=hm.counters.rejected, detail=hm.detail or self._detail(hm),
                        gaps=dict(hm.counters.gaps), dropped=dict(hm.counters.dropped))
        stamp(msg, f"{hm.addr}/status", hm.io.next_seq("/status"), self.clock.now())
        hm.status_pub(encode(msg))
        hm.last_status = self.clock.now()

    def _detail(self, hm: HostedModule) -> str:
        try:
            return hm.module.status_detail()
        except Exception as exc:  # a module's own report failing must not stop its status
            return f"status_detail raised {type(exc).__name__}: {exc}"

    def _fail(self, hm: HostedModule, detail: str) -> None:
        hm.counters.errors += 1
        hm.detail = detail
        self.log.error("%s: %s", hm.addr, detail)
        hm.module.state = Status.ERROR
        self._release(hm)
        try:
            hm.io.emit(Event.ERROR, detail=detail[:500])
            self._publish_status(hm)
        except Exception:  # the transport itself failed; the node keeps running
            self.log.exception("%s: could not report the error", hm.addr)

    def start_autostart(self) -> None:
        for hm in list(self.modules.values()):
            if hm.cfg.autostart:
                reply = self.handle_control(hm, ControlRequest(cmd=Command.RUN))
                if not reply.ok:
                    self.log.error("%s: autostart refused: %s", hm.addr, reply.error)

    def tick(self) -> float:
        """Step every running module that is due, layer by layer (:data:`STEP_ORDER`); returns the time the next one is due."""
        now = self.clock.now()
        self._ticked = True
        next_due = now + STATUS_PERIOD
        for hm in self._order:  # a list replaced, never changed, as modules come and go
            with hm.lock:
                m = hm.module
                # (a nanosecond of slack: a module at the world's tick rate must not skip a tick on rounding)
                if m.state == Status.RUNNING and (hm.woken or now + 1e-9 >= hm.next_due):
                    period = 1.0 / max(m.params.rate_hz, 1e-3)
                    if hm.woken:
                        hm.woken, hm.next_due = False, now + period
                    else:
                        hm.next_due = max(hm.next_due + period, now) if hm.next_due > now - period else now + period
                    t0, cpu0 = time.monotonic(), time.thread_time()
                    try:
                        status = m.step()
                    except Exception as exc:
                        self._fail(hm, f"step raised {type(exc).__name__}: {exc}\n{traceback.format_exc(limit=3)}")
                        continue
                    finally:
                        hm.counters.cpu += time.thread_time() - cpu0
                    took = time.monotonic() - t0
                    if took > SLOW_STEP and self.tick_no >= 0:  # what keeps a lockstep world waiting
                        self.log.warning("%s: one step took %.1f s (tick %d)", hm.addr, took, self.tick_no)
                    hm.counters.steps += 1
                    if status != Status.RUNNING:
                        m.state = status
                        self._release(hm)
                        event = STATUS_EVENT.get(status)
                        if event is not None and event not in hm.io.emitted:  # a primitive's own outcome has its values
                            hm.io.emit(event, values=dict(m.result))
                        self._publish_status(hm)
                if now - hm.last_status >= STATUS_PERIOD:
                    self._publish_status(hm)
                if m.state == Status.RUNNING:
                    next_due = min(next_due, hm.next_due)
        for key, hook in self._hooks.items():
            try:
                hook.after_tick()
                if hook.active():  # a wall-clock node ticks at the hook's rate while it works
                    next_due = min(next_due, now + 1.0 / hook.rate_hz)
            except Exception:  # a hook's fault is logged; the node's loop goes on
                self.log.exception("tick hook %s raised", key)
        return next_due

    def attach(self, key: str, hook: TickHook) -> None:
        """Run ``hook.after_tick()`` after the modules of every tick (once per ``key``); while
        ``hook.active()``, a wall-clock node ticks at the hook's rate. A robot's arm controllers
        follow what the tick's primitives commanded this way, in the same tick."""
        with self._lock:
            if key not in self._hooks:
                self._hooks = {**self._hooks, key: hook}

    def run(self) -> None:
        """Block, stepping modules until :meth:`shutdown`; a lockstep node answers every world tick.

        A loop that dies takes the node's liveliness down with it (:attr:`dead` is set, the node
        exits non-zero): never alive with a dead loop, so a supervisor restarts it and the broker
        fails over.
        """
        try:
            self._loop()
        except Exception:
            self.log.exception("node %s: its loop died; taking the node down", self.config.node)
            self.dead.set()
            self._stop.set()
            if self._node_token is not None:
                self._node_token.close()
                self._node_token = None
            for hm in list(self.modules.values()):  # each module stopped, its claims and keys released
                try:
                    self._retire(hm)
                except Exception:
                    self.log.exception("%s: could not be taken down", hm.addr)
            self.clock.close()  # a lockstep node's token too: the world stops waiting for its answers

    def _loop(self) -> None:
        clock = self.clock
        if isinstance(clock, LockstepClock):
            clock.announce()
            threading.Thread(target=self._beat, args=(clock,), daemon=True, name=f"{self.config.node}-beat").start()
            while (got := clock.wait_tick(self._stop)) is not None:
                k, marks, lag = got
                with self._ack_lock:
                    self._stepping = (k, time.monotonic())
                with self._delivery:
                    self.tick_no, self.lag = k, lag
                self._await_marks(k, marks)
                with self._lock:
                    hosted = list(self.modules.values())
                for hm in hosted:
                    hm.io.release(k - lag)
                self.tick()
                with self._ack_lock:
                    busy = self._busy()
                    clock.ack(k, self._take_marks(), busy)
                    self._acked, self._stepping = (k, busy), None
            return
        while not self._stop.is_set():
            due = self.tick()
            clock.wait_until(due, self._wake)
            self._wake.clear()

    def _beat(self, clock: LockstepClock) -> None:
        """Lockstep: while the step of one tick lasts, tell the world every WORK_BEAT that the node is still at
        it (a first plan on a loaded machine can take longer than the world's deadline), so the world waits
        instead of holding the node's robots. The loop's own thread is busy; this one ends with the loop."""
        while not self._stop.wait(WORK_BEAT / 4):
            with self._ack_lock:
                stepping = self._stepping
                if stepping is not None and time.monotonic() - stepping[1] >= WORK_BEAT:
                    clock.ack(stepping[0], working=True)
                    self._stepping = (stepping[0], time.monotonic())

    # -- idle and busy ----------------------------------------------------------------------
    def wake(self, hm: HostedModule) -> None:
        """Step ``hm`` at the next tick (work reached it off the loop) and resume a paused world."""
        hm.woken = True
        self._wake.set()
        self._resume()

    def _busy(self) -> bool:
        """Whether a module of the node has work under way (:meth:`Module.busy`).

        Tick hooks do not count: an arm still moving when the last primitive ended (a twist or an
        admittance left on) would keep a world with ``idle: pause`` running for as long as it
        moves, and the next task would start at a tick that depends on the wall clock. Paused,
        the world's time stands still for the hook too, and its motion goes on at the resume.
        """
        for hm in self._order:
            try:
                if hm.module.busy():
                    return True
            except Exception:  # a module's own busy() failing must not stop the node's acks
                self.log.exception("%s: busy() raised", hm.addr)
        return False

    def _resume(self) -> None:
        """Lockstep: if the node acked its last tick idle and now has work, ack that tick again, busy,
        so a world paused while its nodes were idle (``idle: pause``) runs the next tick. Between two
        ticks only; the ack of the tick being stepped tells the world anyway."""
        if not isinstance(self.clock, LockstepClock):
            return
        with self._ack_lock:
            acked = self._acked
            if acked is None or acked[1] or acked[0] != self.tick_no or not self._busy():
                return
            # the marks of what was sent since that ack go with it: the world passes them on with the
            # next tick, so the nodes step it with those messages in any process layout
            self.clock.ack(acked[0], self._take_marks(), True)
            self._acked = (acked[0], True)

    # -- lockstep delivery -----------------------------------------------------------------
    def mark(self, key: str, source: str, seq: int) -> None:
        """Note a message a module published (a lockstep node's ack names the last one per stream)."""
        if isinstance(self.clock, LockstepClock):
            with self._delivery:
                self._marks[(key, source)] = seq

    def _take_marks(self) -> list[Mark]:
        with self._delivery:
            marks, self._marks = self._marks, {}
        return [Mark(key=k, source=src, seq=seq) for (k, src), seq in marks.items()]

    def delivered(self) -> None:
        with self._delivery:
            self._delivery.notify_all()

    def _await_marks(self, tick: int, marks: list[Mark]) -> None:
        """Wait until every input subscribed to a marked stream has its marked message, so the tick's
        step sees what the nodes sent during the previous tick whatever the delivery delays."""
        if not marks:
            return
        with self._lock:
            wanted = [(hm, port, m) for hm in self.modules.values() for port, key in hm.in_keys.items()
                      for m in marks if _marked(key, m.key)]
        wanted = self._plausible(tick, wanted)
        if not wanted:
            return
        end = time.monotonic() + MARK_WAIT
        with self._delivery:
            while not self._stop.is_set():
                missing = [(hm, port, m) for hm, port, m in wanted if hm.io.heard(port, m.source) < m.seq]
                if not missing:
                    return
                left = end - time.monotonic()
                if left <= 0:
                    break
                self._delivery.wait(min(left, 0.05))
        if not self._stop.is_set():
            self.mark_timeouts += 1
            hm, port, m = missing[0]
            self.log.warning("tick %d stepped without %d marked message(s), e.g. %s seq %d for %s.%s",
                             tick, len(missing), m.source, m.seq, hm.addr, port)

    def _plausible(self, tick: int, wanted: list[tuple[HostedModule, str, Mark]]) -> list[tuple[HostedModule, str, Mark]]:
        """The marks worth waiting for: those within MAX_MARK_LEAD of what their port heard (others counted)."""
        kept, refused = [], []
        for w in wanted:
            hm, port, m = w
            (kept if m.seq <= hm.io.heard(port, m.source) + MAX_MARK_LEAD else refused).append(w)
        if refused:
            self.marks_refused += 1
            if self.marks_refused <= 10:
                hm, port, m = refused[0]
                self.log.warning("tick %d: mark %s seq %d for %s.%s is over %d ahead of the stream: not waited for",
                                 tick, m.source, m.seq, hm.addr, port, MAX_MARK_LEAD)
        return kept

    def start(self, host_name: str | None = None) -> None:
        """Announce the node, autostart modules and run the loop on a thread."""
        self._node_token = self.transport.token(self.ks.alive_node(host_name or self.config.host, self.config.node))
        self.start_autostart()
        self._thread = threading.Thread(target=self.run, name=f"host-{self.config.node}", daemon=True)
        self._thread.start()

    def remove(self, addr: ModuleAddr) -> None:
        """Take a module off the node: stopped if it runs, its claims released, its keys undeclared."""
        with self._lock:
            hm = self.modules.pop((addr.robot, addr.module), None)
            self._order = [h for h in self._order if h is not hm]
        if hm is not None:
            self._retire(hm)

    def _retire(self, hm: HostedModule) -> None:
        with hm.lock:
            if hm.module.state == Status.RUNNING:
                try:
                    hm.module.stop()
                except Exception:
                    self.log.exception("%s: stop raised", hm.addr)
                hm.module.state = Status.STOPPED
                self._publish_status(hm)
            self._release(hm)
            for h in hm.handles:
                h.close()
            hm.handles.clear()

    def shutdown(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        for hm in list(self.modules.values()):
            self._retire(hm)
        if self._node_token is not None:
            self._node_token.close()
        self.clock.close()


@functools.lru_cache(maxsize=4096)
def _marked(subscription: str, key: str) -> bool:
    """Whether an input subscribed to ``subscription`` receives what is published on ``key`` (cached: every tick asks)."""
    return key_matches(subscription, key)
