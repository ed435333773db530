"""The one module that builds every zenoh key expression of a contactflow site.

Layout (``docs/protocol.md`` documents it with examples)::

    cf/<site>/clock[/<cell>]                               simulation clock (of one cell's world)
    cf/<site>/m/<robot>/<node>/<module>/out/<port>         module data output
    cf/<site>/m/<robot>/<node>/<module>/evt                module events
    cf/<site>/m/<robot>/<node>/<module>/status             module status
    cf/<site>/m/<robot>/<node>/<module>/ctl                control queryable
    cf/<site>/contacts/<robot>/<generator>                 contact hypothesis clouds
    cf/<site>/contacts/fused/<robot>/{hypotheses,contacts,events,objects,claims}
    cf/<site>/broker/dispatch                              broker queryable (ATD in)
    cf/<site>/broker/progress/<task_id>                    abstract progress stream
    cf/<site>/broker/robots/<robot>/{caps,translate,run}   per-robot broker queryables
    cf/<site>/eval/<robot>/<stream>                        ground truth, for evaluation only
    cf/<site>/predict/<robot>/{state,mismatch,ask,ahead}   a robot's predictor (thesis ch. 5): predicted state, mismatches,
                                                           look-ahead questions and answers
    cf/<site>/robot/<robot>/{state,joints,command,camera,depth,info}
                                                           a world's robot: state per tick, commands in, camera
                                                           frames on request, depth stream, description (queryable)
    cf/<site>/camera/<camera>/depth                        a world's fixed camera (no robot carries it): depth stream
    cf/<site>/lockstep/[<cell>/]<node>                     lockstep: a node finished a world tick
    cf/<site>/alive/lockstep/[<cell>/]<node>               liveliness: a node the world waits for each tick
    cf/<site>/alive/controller/<robot>/<node>              liveliness: a node commanding a world's robot
    cf/<site>/alive/node/<host>/<node>                     liveliness: node process
    cf/<site>/alive/m/<robot>/<node>/<module>              liveliness: module
    cf/<site>/alive/robot/<robot>                          liveliness: robot advertising
    cf/<site>/alive/claim/<robot>/<resource>/<node>/<module>/<mode>
                                                           liveliness: resource claim, mode excl | mix
    cf/<site>/bench/<stack>/<size>/<phase>/<round>         messaging benchmark streams
    cf/<site>/bench/ctl/<signal>                           messaging benchmark signals (ready, done)

``<robot>`` is ``site`` for modules that belong to no robot (the broker, a shared
integrator). Subscribers address a module without knowing its node through ``*``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

ROOT = "cf"
SITE_ROBOT = "site"
"""Robot segment of modules that belong to the site, not to one robot."""
RESERVED = frozenset({"fused", "*", "**"})
_SEGMENT = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$")
ANY = "*"
CLAIM_MODES = ("excl", "mix")
"""A claim is exclusive, or shared by modules that all declare weighted mixing (thesis §6.3.1)."""
BENCH_SIGNALS = ("ready", "done")
ROBOT_STREAMS = ("state", "joints", "command", "camera", "depth", "info")
"""A world's robot: its state each tick, the commands it takes, camera frames, its description."""
PREDICT_STREAMS = ("state", "mismatch", "ask", "ahead")
"""A robot's predictor: what its simulation predicts each tick, where prediction and sensing disagree, and
look-ahead questions (``ask``) and their answers (``ahead``)."""
FUSED_STREAMS = ("hypotheses", "contacts", "events", "objects", "claims")
"""A fusion's (a robot's or a cell's): fused cloud, contacts, contact events, the objects its contacts touched
(its object map) and the robots' claims on them."""


class KeyExprError(ValueError):
    """A name cannot be used as a key-expression segment."""


def segment(value: str, field: str) -> str:
    """Validate one key segment; ``field`` names what the value is, for the error."""
    if value == ANY:
        return value
    if not isinstance(value, str) or not _SEGMENT.match(value):
        raise KeyExprError(
            f"{field}={value!r} is not a valid key segment (letters, digits, _ . - ; "
            "no '/', '*', '$', '#', '?', not empty)"
        )
    return value


@dataclass(frozen=True, slots=True)
class ModuleAddr:
    """Where a module lives: robot, node and module name."""

    robot: str
    node: str
    module: str

    def __str__(self) -> str:
        return f"{self.robot}/{self.node}/{self.module}"


@dataclass(frozen=True, slots=True)
class KeySpace:
    """Key expressions of one site (the site prefix isolates deployments)."""

    site: str = "default"

    def __post_init__(self) -> None:
        segment(self.site, "site")

    @property
    def prefix(self) -> str:
        return f"{ROOT}/{self.site}"

    # -- clock -------------------------------------------------------------------------
    def clock(self, cell: str = "") -> str:
        """The clock of a world; a site running several worlds (cells) names each."""
        return f"{self.prefix}/clock" + (f"/{segment(cell, 'cell')}" if cell else "")

    # -- modules -----------------------------------------------------------------------
    def module(self, robot: str, node: str, module: str) -> str:
        segment(robot, "robot")
        segment(node, "node")
        segment(module, "module")
        return f"{self.prefix}/m/{robot}/{node}/{module}"

    def output(self, robot: str, node: str, module: str, port: str) -> str:
        return f"{self.module(robot, node, module)}/out/{segment(port, 'port')}"

    def events(self, robot: str = ANY, node: str = ANY, module: str = ANY) -> str:
        return f"{self.module(robot, node, module)}/evt"

    def status(self, robot: str = ANY, node: str = ANY, module: str = ANY) -> str:
        return f"{self.module(robot, node, module)}/status"

    def control(self, robot: str, node: str, module: str) -> str:
        return f"{self.module(robot, node, module)}/ctl"

    def parse_module(self, key: str) -> tuple[ModuleAddr, str]:
        """Split a module key into its address and the rest (``out/<port>``, ``evt``, ...)."""
        parts = str(key).split("/")
        if len(parts) < 7 or parts[:3] != [ROOT, self.site, "m"]:
            raise KeyExprError(f"key {key!r} is not a module key of site {self.site!r}")
        return ModuleAddr(parts[3], parts[4], parts[5]), "/".join(parts[6:])

    # -- contacts ----------------------------------------------------------------------
    def hypotheses(self, robot: str = ANY, generator: str = ANY) -> str:
        if robot in RESERVED - {ANY}:
            raise KeyExprError(f"robot={robot!r} is reserved in contacts/<robot>/<generator>")
        return f"{self.prefix}/contacts/{segment(robot, 'robot')}/{segment(generator, 'generator')}"

    def fused(self, robot: str = ANY, stream: str = "events") -> str:
        if stream not in FUSED_STREAMS:
            raise KeyExprError(f"stream={stream!r}: fused streams are {', '.join(FUSED_STREAMS)}")
        return f"{self.prefix}/contacts/fused/{segment(robot, 'robot')}/{stream}"

    # -- broker ------------------------------------------------------------------------
    def dispatch(self) -> str:
        return f"{self.prefix}/broker/dispatch"

    def progress(self, task_id: str = ANY) -> str:
        return f"{self.prefix}/broker/progress/{segment(task_id, 'task_id')}"

    def robot_service(self, robot: str, verb: str) -> str:
        if verb not in ("caps", "translate", "run", "cancel"):
            raise KeyExprError(f"verb={verb!r}: robot services are caps, translate, run, cancel")
        return f"{self.prefix}/broker/robots/{segment(robot, 'robot')}/{verb}"

    # -- a world's robots (the interface layer) ----------------------------------------
    def robot(self, robot: str = ANY, stream: str = ANY) -> str:
        if stream != ANY and stream not in ROBOT_STREAMS:
            raise KeyExprError(f"stream={stream!r}: robot streams are {', '.join(ROBOT_STREAMS)}")
        return f"{self.prefix}/robot/{segment(robot, 'robot')}/{stream}"

    def camera(self, camera: str = ANY) -> str:
        """The depth stream of a world's fixed camera (a scene file's ``cameras``)."""
        return f"{self.prefix}/camera/{segment(camera, 'camera')}/depth"

    def lockstep(self, node: str = ANY, cell: str = "") -> str:
        """Where a lockstep node says it finished a tick of its cell's world."""
        return f"{self.prefix}/lockstep/" + (f"{segment(cell, 'cell')}/" if cell else "") + segment(node, "node")

    def alive_lockstep(self, node: str = ANY, cell: str = "") -> str:
        return f"{self.prefix}/alive/lockstep/" + (f"{segment(cell, 'cell')}/" if cell else "") + segment(node, "node")

    def alive_controller(self, robot: str = ANY, node: str = ANY) -> str:
        return f"{self.prefix}/alive/controller/{segment(robot, 'robot')}/{segment(node, 'node')}"

    # -- prediction (thesis ch. 5) ----------------------------------------------------
    def predict(self, robot: str = ANY, stream: str = ANY) -> str:
        if stream != ANY and stream not in PREDICT_STREAMS:
            raise KeyExprError(f"stream={stream!r}: predictor streams are {', '.join(PREDICT_STREAMS)}")
        return f"{self.prefix}/predict/{segment(robot, 'robot')}/{stream}"

    # -- evaluation (ground truth; primitives and fusion never subscribe) -------------
    def evaluation(self, robot: str = ANY, stream: str = ANY) -> str:
        return f"{self.prefix}/eval/{segment(robot, 'robot')}/{segment(stream, 'stream')}"

    # -- liveliness --------------------------------------------------------------------
    def alive_node(self, host: str = ANY, node: str = ANY) -> str:
        return f"{self.prefix}/alive/node/{segment(host, 'host')}/{segment(node, 'node')}"

    def alive_module(self, robot: str = ANY, node: str = ANY, module: str = ANY) -> str:
        return (
            f"{self.prefix}/alive/m/{segment(robot, 'robot')}/{segment(node, 'node')}/"
            f"{segment(module, 'module')}"
        )

    def alive_robot(self, robot: str = ANY) -> str:
        return f"{self.prefix}/alive/robot/{segment(robot, 'robot')}"

    def claim(self, robot: str, resource: str, node: str = ANY, module: str = ANY, mode: str = ANY) -> str:
        if mode != ANY and mode not in CLAIM_MODES:
            raise KeyExprError(f"mode={mode!r}: claims are {' or '.join(CLAIM_MODES)}")
        return (
            f"{self.prefix}/alive/claim/{segment(robot, 'robot')}/"
            f"{segment(resource, 'resource')}/{segment(node, 'node')}/{segment(module, 'module')}/{mode}"
        )

    @staticmethod
    def parse_claim(key: str) -> tuple[str, str, str]:
        """``(node, module, mode)`` of a claim token's key."""
        parts = str(key).split("/")
        if len(parts) != 9 or parts[2:4] != ["alive", "claim"] or parts[8] not in CLAIM_MODES:
            raise KeyExprError(f"key {key!r} is not a resource claim")
        return parts[6], parts[7], parts[8]

    # -- benchmarks --------------------------------------------------------------------
    def bench(self, stack: str = ANY, size: str = ANY, phase: str = ANY, rnd: str = ANY) -> str:
        """A messaging benchmark stream (``rnd`` is the round, as text)."""
        return (
            f"{self.prefix}/bench/{segment(stack, 'stack')}/{segment(size, 'size')}/"
            f"{segment(phase, 'phase')}/{segment(rnd, 'round')}"
        )

    def bench_signal(self, signal: str) -> str:
        """A messaging benchmark control signal: ``ready`` (liveliness) or ``done`` (put)."""
        if signal not in BENCH_SIGNALS:
            raise KeyExprError(f"signal={signal!r}: benchmark signals are {', '.join(BENCH_SIGNALS)}")
        return f"{self.prefix}/bench/ctl/{signal}"

    def everything(self) -> str:
        return f"{self.prefix}/**"
