"""Node configuration (YAML): zenoh settings, clock, and the modules a node hosts.

Example::

    site: lab
    node: control
    host: control-pc
    robot: tombatossals          # default robot of the modules below
    clock: wall                  # wall | sim (follow the world's clock) | lockstep (the world waits for this node each tick)
    cell: ""                     # with sim/lockstep: the world (cell) to follow, when the site runs several
    zenoh: {mode: peer, listen: [tcp/127.0.0.1:7501], connect: [], multicast_scouting: false}
    modules:
      - name: source
        type: signal_source      # short name, or pkg.mod:Class (also looked up next to this file)
        params: {rate_hz: 50, amplitude: 1.0}
      - name: filter
        type: lowpass
        inputs: {in: source.signal}        # [robot/]module.port, or a key expression cf/...
        mix: {arm_left: 0.5}               # share a commanded resource with weight 0.5; every
                                           # module commanding arm_left must declare mixing
        autostart: true
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from contactflow.nodes.keys import KeyExprError, KeySpace, segment
from contactflow.nodes.module import Layer, Module
from contactflow.nodes.params import ParamError, replace_params
from contactflow.nodes.registry import UnknownModuleType, resolve
from contactflow.nodes.transport import ZenohSettings
from contactflow.nodes.yamldoc import ConfigError, YamlDoc

_NODE_KEYS = {"site", "node", "host", "robot", "clock", "cell", "zenoh", "modules"}
_MODULE_KEYS = {"name", "type", "robot", "params", "inputs", "outputs", "autostart", "mix"}
_ZENOH_KEYS = {"mode", "listen", "connect", "multicast_scouting", "config_file"}


@dataclass(frozen=True)
class Source:
    """Where an input port reads from: a module output, or a raw key expression."""

    robot: str | None = None
    module: str = ""
    port: str = ""
    key: str | None = None

    def keyexpr(self, ks: KeySpace, default_robot: str) -> str:
        if self.key is not None:
            return self.key
        return ks.output(self.robot or default_robot, "*", self.module, self.port)


@dataclass(frozen=True)
class ModuleConfig:
    name: str
    type: str
    cls: type[Module]
    params: Any
    robot: str
    inputs: dict[str, Source] = field(default_factory=dict)
    outputs: dict[str, str] = field(default_factory=dict)  # port -> explicit key expression
    autostart: bool = True
    mix: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class NodeConfig:
    site: str
    node: str
    host: str
    robot: str
    clock: str
    zenoh: ZenohSettings
    modules: tuple[ModuleConfig, ...]
    file: str = "<config>"
    cell: str = ""  # the world (cell) whose clock a sim or lockstep node follows; "" the site's only one

    @property
    def keyspace(self) -> KeySpace:
        return KeySpace(self.site)


def parse_source(text: str) -> Source:
    if text.startswith("cf/"):
        return Source(key=text)
    robot = None
    if "/" in text:
        robot, _, text = text.partition("/")
    module, dot, port = text.rpartition(".")
    if not dot or not module or not port:
        raise ValueError(f"{text!r} is not [robot/]module.port or a key expression cf/...")
    for value, what in ((robot, "robot"), (module, "module"), (port, "port")):
        if value is not None:
            segment(value, what)
    return Source(robot=robot, module=module, port=port)


def _str_list(doc: YamlDoc, path: tuple) -> tuple[str, ...]:
    items = doc.get(path, list, [])
    for i, _ in enumerate(items):
        doc.get(path + (i,), str)
    return tuple(items)


def parse_zenoh(doc: YamlDoc, path: tuple) -> ZenohSettings:
    if doc.get(path, dict, None) is None:
        return ZenohSettings()
    doc.mapping(path, _ZENOH_KEYS)
    mode = doc.get(path + ("mode",), str, "peer")
    if mode not in ("peer", "client", "router"):
        raise doc.error(path + ("mode",), f"{mode!r} is not peer, client or router")
    cfg_file = doc.get(path + ("config_file",), str, None)
    if cfg_file is not None and not Path(cfg_file).is_absolute():
        cfg_file = str(Path(doc.file).parent / cfg_file)
    return ZenohSettings(
        mode=mode,
        listen=_str_list(doc, path + ("listen",)),
        connect=_str_list(doc, path + ("connect",)),
        multicast_scouting=doc.get(path + ("multicast_scouting",), bool, False),
        config_file=cfg_file,
    )


def mix_problem(cls: type[Module], resource: str) -> str:
    """Why ``cls`` cannot mix ``resource`` by weight, or "" when it can."""
    if resource not in cls.resources:
        return f"{cls.__name__} commands no resource {resource!r} (resources: {list(cls.resources)})"
    ports = [p for p in cls.outputs if p.resource == resource]
    if not ports:
        return (f"{cls.__name__} has no output port commanding {resource!r}, so there is no message "
                f"to carry the mixing weight")
    for p in ports:
        if not p.mixable:
            return f"{cls.__name__}.{p.name} sends {p.type.__name__}, which has no weight field to mix by"
    return ""


def _parse_module(doc: YamlDoc, path: tuple, robot_default: str) -> ModuleConfig:
    doc.mapping(path, _MODULE_KEYS)
    name = doc.get(path + ("name",), str)
    type_name = doc.get(path + ("type",), str)
    robot = doc.get(path + ("robot",), str, robot_default)
    for value, what in ((name, "name"), (robot, "robot")):
        try:
            segment(value, what)
        except KeyExprError as exc:
            raise doc.error(path + (what,), str(exc)) from None
    doc_file = Path(doc.file)
    try:
        cls = resolve(type_name, doc_file.parent if doc_file.is_file() else None)
    except UnknownModuleType as exc:
        raise doc.error(path + ("type",), str(exc)) from None
    raw_params = doc.get(path + ("params",), dict, {})
    try:
        params = replace_params(cls.Params(), raw_params)
    except ParamError as exc:
        bad = str(exc).split(":", 1)[0]
        raise doc.error(path + ("params", bad), str(exc).split(":", 1)[-1].strip()) from None
    inputs: dict[str, Source] = {}
    in_ports = {p.name for p in cls.inputs}
    for port in doc.get(path + ("inputs",), dict, {}):
        if port not in in_ports:
            raise doc.error(path + ("inputs", port), f"{cls.__name__} has no input {port!r} (inputs: {sorted(in_ports)})")
        try:
            inputs[port] = parse_source(doc.get(path + ("inputs", port), str))
        except (ValueError, KeyExprError) as exc:
            raise doc.error(path + ("inputs", port), str(exc)) from None
    outputs: dict[str, str] = {}
    out_ports = {p.name for p in cls.outputs}
    for port in doc.get(path + ("outputs",), dict, {}):
        if port not in out_ports:
            raise doc.error(path + ("outputs", port), f"{cls.__name__} has no output {port!r} (outputs: {sorted(out_ports)})")
        key = doc.get(path + ("outputs", port), str)
        if not key.startswith("cf/") or any(c in key for c in "*$#?"):
            raise doc.error(path + ("outputs", port), f"{key!r} is not a concrete key expression under cf/")
        outputs[port] = key
    mix: dict[str, float] = {}
    for res in doc.get(path + ("mix",), dict, {}):
        weight = doc.get(path + ("mix", res), float)
        if not 0.0 < weight <= 1.0:
            raise doc.error(path + ("mix", res), f"weight {weight} is not in (0, 1]")
        problem = mix_problem(cls, res)
        if problem:
            raise doc.error(path + ("mix", res), problem)
        mix[res] = weight
    default_start = cls.autostart if cls.autostart is not None else cls.layer in (Layer.INTERFACE, Layer.SERVICE)
    autostart = doc.get(path + ("autostart",), bool, default_start)
    return ModuleConfig(name, type_name, cls, params, robot, inputs, outputs, autostart, mix)


def parse_node_config(doc: YamlDoc) -> NodeConfig:
    doc.mapping((), _NODE_KEYS)
    site = doc.get(("site",), str, "default")
    node = doc.get(("node",), str)
    host = doc.get(("host",), str, node)
    robot = doc.get(("robot",), str, "site")
    for value, what in ((site, "site"), (node, "node"), (host, "host"), (robot, "robot")):
        try:
            segment(value, what)
        except KeyExprError as exc:
            raise doc.error((what,), str(exc)) from None
    clock = doc.get(("clock",), str, "wall")
    if clock not in ("wall", "sim", "lockstep"):
        raise doc.error(("clock",), f"{clock!r} is not wall, sim or lockstep")
    cell = doc.get(("cell",), str, "")
    if cell:
        try:
            segment(cell, "cell")
        except KeyExprError as exc:
            raise doc.error(("cell",), str(exc)) from None
    modules = []
    names: set[str] = set()
    for i, _ in enumerate(doc.get(("modules",), list, [])):
        m = _parse_module(doc, ("modules", i), robot)
        if (m.robot, m.name) in names:
            raise doc.error(("modules", i, "name"), f"module {m.robot}/{m.name} is defined twice")
        names.add((m.robot, m.name))
        modules.append(m)
    _check_wiring(doc, modules)
    return NodeConfig(site, node, host, robot, clock, parse_zenoh(doc, ("zenoh",)), tuple(modules), doc.file, cell)


def _check_wiring(doc: YamlDoc, modules: list[ModuleConfig]) -> None:
    """An input wired to a module of this node names one of its outputs (a module elsewhere is checked where it runs)."""
    here = {(m.robot, m.name): m for m in modules}
    for i, m in enumerate(modules):
        for port, src in m.inputs.items():
            source = here.get((src.robot or m.robot, src.module)) if src.key is None else None
            if source is None:
                continue
            outs = {p.name for p in source.cls.outputs}
            if src.port not in outs:
                raise doc.error(("modules", i, "inputs", port),
                                f"module {source.name!r} ({source.cls.__name__}) has no output {src.port!r} "
                                f"(outputs: {sorted(outs)})")


def load_node_config(path: str | Path) -> NodeConfig:
    return parse_node_config(YamlDoc.load(path))


__all__ = ["ConfigError", "ModuleConfig", "NodeConfig", "Source", "load_node_config", "mix_problem", "parse_node_config"]
