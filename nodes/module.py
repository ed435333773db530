"""Module base class: the four layers (thesis §6.1), module description and lifecycle hooks.

A module is a small class with a frozen ``Params`` dataclass, declared inputs, outputs and
events, and the hooks ``setup(io)``, ``start()``, ``step() -> Status``, ``stop()`` and
``reset()``. Constructors do no I/O: everything the module touches comes through the
:class:`ModuleIO` handed to ``setup``, which the node implements over zenoh and
:mod:`contactflow.nodes.testing` implements in memory.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any, ClassVar, Protocol

import yaml

from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Command, ControlReply, ParamValue
from contactflow.nodes.params import ParamError, params_dict, replace_params
from contactflow.nodes.status import Event, Status
from contactflow.nodes.wire import Message, MsgId


class Layer(StrEnum):
    """The four layers of thesis §6.1."""

    INTERFACE = "interface"
    SERVICE = "service"
    PRIMITIVE = "primitive"
    TASK = "task"


@dataclass(frozen=True, slots=True)
class Port:
    """A typed input or output of a module."""

    name: str
    type: type[Message]
    doc: str = ""
    resource: str = ""
    """The shared resource an output commands (one of the module's ``resources``); a
    configuration that mixes it (``mix: {resource: weight}``) has the host write the weight
    into every message on this port, so the message type needs a float ``weight`` field."""

    @property
    def mixable(self) -> bool:
        """The message type carries a ``weight`` the host can set for weighted mixing."""
        return "weight" in getattr(self.type, "__struct_fields__", ())


class LayerError(TypeError):
    """A module breaks a rule of its layer (e.g. a service sending control messages)."""


class ModuleIO(Protocol):
    """Everything a module may do to the outside world."""

    @property
    def now(self) -> float:
        """Current time of the node's clock (simulated or wall), in seconds."""
        ...

    def latest(self, port: str) -> Message | None:
        """Newest message received on an input port, or None."""
        ...

    def take(self, port: str) -> list[Message]:
        """Every message received on an input port since the last call, oldest first."""
        ...

    def wired(self, port: str) -> bool:
        """Whether an input port reads from a source (an unwired port never receives)."""
        ...

    def publish(self, port: str, msg: Message, inputs: list[MsgId] | None = None) -> None:
        """Send on an output port; ``inputs`` defaults to the ids of the newest inputs."""
        ...

    def emit(self, event: Event, detail: str = "", values: dict[str, float] | None = None) -> None:
        """Raise an event (primitives and tasks), stamped with the node's one clock."""
        ...

    def command(self, target: str, cmd: Command, params: dict[str, ParamValue] | None = None) -> ControlReply:
        """Send a control message to another module (``robot/module`` or ``module``)."""
        ...

    def log(self, text: str) -> None:
        ...

    def wake(self) -> None:
        """Work arrived off the step loop (on a queryable's thread): step the module at the node's
        next tick; a lockstep world paused while its nodes were idle resumes for it."""
        ...


class Module:
    """Base of every service, primitive, task and interface module."""

    layer: ClassVar[Layer] = Layer.SERVICE
    inputs: ClassVar[tuple[Port, ...]] = ()
    outputs: ClassVar[tuple[Port, ...]] = ()
    events: ClassVar[tuple[Event, ...]] = ()
    resources: ClassVar[tuple[str, ...]] = ()
    """Shared resources the module commands (e.g. ``arm_left``); see thesis §6.6."""
    autostart: ClassVar[bool | None] = None
    """Run when the node starts; None: interface and service modules do, the others wait."""

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 10.0  # Hz, loop rate

    def __init__(self, name: str, params: Any = None) -> None:
        self.name = name
        self.params = params if params is not None else self.Params()
        self.io: ModuleIO | None = None
        self.state = Status.IDLE
        self.result: dict[str, float] = {}  # what a finished run reports with its outcome event

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("abstract", False):
            return
        if cls.layer in (Layer.SERVICE, Layer.PRIMITIVE) and not cls.outputs and not cls.events:
            raise LayerError(f"{cls.__name__}: a {cls.layer} module generates at least one output")
        if not hasattr(cls.Params, "rate_hz"):
            raise LayerError(f"{cls.__name__}.Params needs a rate_hz field")
        for p in cls.outputs:
            if p.resource and p.resource not in cls.resources:
                raise LayerError(f"{cls.__name__}: output {p.name!r} commands resource {p.resource!r}, "
                                 f"which is not in resources {cls.resources}")

    # -- lifecycle hooks (override) ------------------------------------------------------
    def setup(self, io: ModuleIO) -> None:
        """Attach the module to its I/O; called once before the first ``start``."""
        self.io = io

    def start(self) -> None:
        """Called when the module is told to run."""

    def step(self) -> Status:
        """One iteration of the loop at ``params.rate_hz``."""
        return Status.RUNNING

    def stop(self) -> None:
        """Called when the module is told to stop (it may be started again)."""

    def reset(self) -> None:
        """Return to the initial internal state."""

    def on_params(self, old: Any) -> None:
        """Called after an online parameter change."""

    def busy(self) -> bool:
        """Whether the module has work under way (a running primitive or task): a lockstep world
        with ``idle: pause`` advances only while a module of its nodes is busy. Services, which
        run all the time, never are."""
        return self.state is Status.RUNNING and self.layer in (Layer.PRIMITIVE, Layer.TASK)

    def status_detail(self) -> str:
        """What a healthy module says in its status besides its state (``contactflow ls``); "" for nothing."""
        return ""

    def claimed_resources(self) -> tuple[str, ...]:
        """The shared resources a run with the current parameters commands (claimed on RUN).

        The class's ``resources`` by default; a module whose parameters choose what it commands
        (a primitive's ``arm``) narrows them to that.
        """
        return self.resources

    # -- helpers -------------------------------------------------------------------------
    def set_params(self, changes: dict[str, Any]) -> None:
        old = self.params
        self.params = replace_params(old, changes, where=f"{self.name}.params.")
        self.on_params(old)

    @property
    def may_command(self) -> bool:
        return self.layer in (Layer.PRIMITIVE, Layer.TASK, Layer.INTERFACE)

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        """Key expressions input ports read when the configuration names no source.

        Modules that live on a shared part of the key space override it (the fusion service
        reads ``contacts/*/*``); ordinary modules read only what their configuration wires.
        """
        return {}

    @classmethod
    def default_output_keys(cls, ks: KeySpace, robot: str, name: str, params: Any) -> dict[str, str]:
        """Key expressions output ports publish on instead of ``.../<module>/out/<port>``."""
        return {}

    @classmethod
    def describe(cls) -> dict[str, Any]:
        """The module description of thesis §6.2.1: inputs, outputs, parameters, events."""
        return {
            "module": cls.__name__,
            "layer": str(cls.layer),
            "doc": (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else "",
            "inputs": {p.name: p.type.tag() for p in cls.inputs},
            "outputs": {p.name: p.type.tag() for p in cls.outputs},
            "events": [str(e) for e in cls.events],
            "resources": list(cls.resources),
            "params": params_dict(cls.Params()),
        }

    @classmethod
    def describe_yaml(cls) -> str:
        return yaml.safe_dump(cls.describe(), sort_keys=False)

    @classmethod
    def port(cls, direction: str, name: str) -> Port:
        ports = cls.inputs if direction == "in" else cls.outputs
        for p in ports:
            if p.name == name:
                return p
        raise ParamError(f"{cls.__name__} has no {direction}put port {name!r} (has {[p.name for p in ports]})")


