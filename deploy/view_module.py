"""Live view: a module serving the key space to Foxglove over its WebSocket protocol (foxglove-sdk)."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import foxglove

from contactflow.abstraction.messages import AbstractProgressMsg
from contactflow.deploy.foxglove_view import JsonView, ViewTranslator
from contactflow.embodiments.messages import DepthImage, RobotState
from contactflow.embodiments.remote import link
from contactflow.fusion.messages import ContactEventMsg, ContactList, FusedCloud, HypothesisCloud
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Status
from contactflow.recognition.messages import SegmentedObjects


class FoxgloveView(Module):
    """Robots' frames, contact hypotheses (fused and per generator), contacts and events, depth clouds, objects and
    task progress, live in Foxglove.

    Connect Foxglove to ``ws://<host>:<port>``; ``docs/foxglove-layout.json`` arranges the panels.
    """

    layer = Layer.INTERFACE
    autostart = True
    inputs = (
        Port("state", RobotState, "every robot's state (joints -> link frames)"),
        Port("fused", FusedCloud, "fused hypotheses"),
        Port("clouds", HypothesisCloud, "every generator's hypotheses"),
        Port("contacts", ContactList, "condensed contacts"),
        Port("events", ContactEventMsg, "contact events"),
        Port("depth", DepthImage, "depth frames"),
        Port("objects", SegmentedObjects, "segmented objects"),
        Port("progress", AbstractProgressMsg, "dispatched tasks' progress"),
    )

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 20.0  # Hz, how often received messages are sent to the viewers
        host: str = "127.0.0.1"  # address the WebSocket server binds (loopback unless a viewer is elsewhere)
        port: int = 8765  # TCP port of the WebSocket server (0: any free one)
        depth_stride: int = 4  # pixels: a depth cloud keeps every n-th row and column

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: Params) -> dict[str, str]:
        return {"state": ks.robot("*", "state"), "fused": ks.fused("*", "hypotheses"), "clouds": ks.hypotheses("*", "*"),
                "contacts": ks.fused("*", "contacts"), "events": ks.fused("*", "events"),
                "depth": ks.robot("*", "depth"), "objects": ks.output("*", "*", "*", "objects"),
                "progress": ks.progress("*")}

    def setup(self, io) -> None:  # type: ignore[no-untyped-def]
        super().setup(io)
        self.view = ViewTranslator(self.params.depth_stride)
        self.server: foxglove.WebSocketServer | None = None
        self.sent = 0
        self._lock = threading.Lock()
        self._asking: set[str] = set()
        self._learned: list[tuple[str, object]] = []

    def start(self) -> None:
        assert self.io is not None
        # a context per run: its channels go to this server only, and a new viewer gets every robot's URDF again
        self.context = foxglove.Context()
        self.channels: dict[str, foxglove.Channel] = {}
        self._asking.clear()
        self.server = foxglove.start_server(name=f"contactflow {self.io.keyspace.site}", host=self.params.host,
                                            port=self.params.port, context=self.context)

    @property
    def port(self) -> int:
        """The TCP port the server listens on (0 while stopped)."""
        return self.server.port if self.server is not None else 0

    def _learn(self, robot: str) -> None:
        """Ask the robot's world what it is (off the step loop: a query waits for the answer)."""
        assert self.io is not None
        try:
            info = link(self.io.transport, self.io.keyspace, robot, self.io.node).info()
            with self._lock:
                self._learned += self.view.add_robot(info)
        except Exception as exc:  # the other channels are shown anyway, and the robot's next state asks again
            self.io.log(f"no frames for robot {robot} yet: {exc}")
            with self._lock:
                self._asking.discard(robot)

    def _send(self, topic: str, msg: object) -> None:
        ch = self.channels.get(topic)
        if isinstance(msg, JsonView):
            if ch is None:
                ch = self.channels[topic] = foxglove.Channel(topic, schema=msg.schema, message_encoding="json",
                                                             context=self.context)
            ch.log(msg.value)
        else:
            if ch is None:
                schema = type(msg).get_schema()
                ch = self.channels[topic] = foxglove.Channel(topic, schema=schema, message_encoding="protobuf",
                                                             context=self.context)
            ch.log(msg.encode())
        self.sent += 1

    def step(self) -> Status:
        assert self.io is not None
        with self._lock:
            learned, self._learned = self._learned, []
        for topic, msg in learned:
            self._send(topic, msg)
        for port in (p.name for p in self.inputs):
            msgs = self.io.take(port)
            if port in ("state", "depth", "fused", "clouds"):
                msgs = _newest_per_source(msgs)  # a viewer wants the present, not every frame of a burst
            for m in msgs:
                if isinstance(m, RobotState) and m.robot not in self._asking:
                    self._asking.add(m.robot)
                    threading.Thread(target=self._learn, args=(m.robot,), daemon=True).start()
                for topic, vmsg in self.view.translate("", m):
                    self._send(topic, vmsg)
        return Status.RUNNING

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()
            self.server = None


def _newest_per_source(msgs: list) -> list:
    newest = {}
    for m in msgs:
        newest[m.hdr.source] = m
    return list(newest.values())
