"""Records key expressions of a site into an MCAP file (``contactflow record``).

zenoh callbacks only queue the payload; one writer thread decodes, writes the key-space
channel and the Foxglove view channels. A full queue drops (counted), a payload the wire
refuses is counted and left out, and a gap in a source's sequence numbers counts as lost.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from contactflow.deploy.foxglove_view import ViewTranslator
from contactflow.deploy.recording import RecordingWriter, message_types
from contactflow.deploy.seqcheck import SequenceMonitor
from contactflow.embodiments.messages import InfoRequest, RobotInfo, RobotState
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.transport import Handle, Transport
from contactflow.nodes.wire import Message, WireError, decode, decode_any, encode

ASK_AGAIN = 1.0  # s of wall time before a robot's world that did not answer is asked its description again
log = logging.getLogger("contactflow.record")


@dataclass
class RecorderStats:
    """What a recorder saw and wrote."""

    received: int = 0  # samples the subscriptions delivered
    recorded: int = 0  # key-space messages written
    view: int = 0  # Foxglove view messages written
    dropped: int = 0  # samples the recorder's queue had no room for
    rejected: int = 0  # payloads the wire refuses (not MessagePack, unknown type, invalid fields)
    lost: int = 0  # messages missing from a source's sequence numbers
    unviewed: int = 0  # recorded messages the view channels could not show
    bytes: int = 0  # wire bytes received
    seconds: float = 0.0  # s, recording time

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


class Recorder:
    """Subscribes to ``keys`` and writes what arrives into ``path`` until ``stop``."""

    def __init__(self, transport: Transport, keys: list[str], path: Path, site: str, view: bool = True,
                 queue_size: int = 200_000) -> None:
        self.transport = transport
        self.keys = list(keys)
        self.path = Path(path)
        self.ks = KeySpace(site)
        self.view = ViewTranslator() if view else None
        self.stats = RecorderStats()
        self._queue: queue.Queue[tuple[str, bytes, int] | None] = queue.Queue(maxsize=queue_size)
        self._writer = RecordingWriter(self.path, site)
        self._seqs = SequenceMonitor()
        self._handles: list[Handle] = []
        self._thread: threading.Thread | None = None
        self._robots: set[str] = set()  # robots whose world described them (or whose description failed to load)
        self._asking: set[str] = set()  # robots whose description query is under way
        self._asked: dict[str, float] = {}  # robot -> monotonic time of the last unanswered description query
        self._described: list[tuple[str, object]] = []  # view messages of the answers, for the writer thread
        self._view_lock = threading.Lock()
        self._t0 = 0.0
        self._count = threading.Lock()

    def start(self) -> Recorder:
        message_types()
        self._writer.open()
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()
        self._t0 = time.monotonic()
        self._handles = [self.transport.subscribe(k, self._on_sample) for k in self.keys]
        return self

    def _on_sample(self, key: str, payload: bytes) -> None:
        with self._count:  # zenoh may call the subscriptions of several keys at once
            self.stats.received += 1
            self.stats.bytes += len(payload)
            try:
                self._queue.put_nowait((key, payload, time.time_ns()))
            except queue.Full:
                self.stats.dropped += 1

    def _run(self) -> None:
        while (item := self._queue.get()) is not None:
            key, payload, t_ns = item
            try:
                msg = decode_any(payload, key)
            except WireError as exc:
                self.stats.rejected += 1
                log.debug("%s", exc)
                continue
            gap = self._seqs.observe(f"{key} {msg.hdr.source}", msg.hdr.seq) if msg.hdr.seq > 0 else None
            if gap is not None:
                self.stats.lost += gap.count
            self._writer.write(key, msg, t_ns)
            self.stats.recorded += 1
            if self.view is not None:
                try:
                    self._show(key, msg, t_ns)
                except Exception:  # a message the view cannot draw (a robot model that fails to load) is recorded anyway
                    self.stats.unviewed += 1
                    if self.stats.unviewed == 1:
                        log.exception("%s: not drawn in the view channels", key)

    def _show(self, key: str, msg: Message, t_ns: int) -> None:
        assert self.view is not None
        with self._view_lock:
            ask = (isinstance(msg, RobotState) and msg.robot not in self._robots and msg.robot not in self._asking
                   and time.monotonic() - self._asked.get(msg.robot, -ASK_AGAIN) >= ASK_AGAIN)
            if ask:
                self._asking.add(msg.robot)
            described, self._described = self._described, []
        if ask:  # the query waits for the world: off the writer's thread, which keeps recording meanwhile
            threading.Thread(target=self._learn, args=(msg.robot,), name="recorder-describe", daemon=True).start()
        for topic, vmsg in described:
            self._writer.write_view(topic, vmsg, t_ns)
        for topic, vmsg in self.view.translate(key, msg):
            self._writer.write_view(topic, vmsg, t_ns)
            self.stats.view += 1

    def _learn(self, robot: str) -> None:
        """Ask the robot's world what it is, for its links' frames, until it answers: a world too busy to answer
        in time (a loaded machine) is asked again ASK_AGAIN s later, on a later state."""
        assert self.view is not None
        key = self.ks.robot(robot, "info")
        try:
            replies = self.transport.query(key, encode(InfoRequest()), timeout=2.0)
        except Exception as exc:  # the view is a convenience: the key-space channels are recorded anyway
            log.warning("no frames for robot %s yet: %s", robot, exc)
            replies = []
        described: list[tuple[str, object]] = []
        if replies:
            try:
                described = self.view.add_robot(decode(replies[0][1], RobotInfo, replies[0][0]))
            except Exception as exc:  # a description the view cannot load: no frames for that robot, asked once
                log.warning("no frames for robot %s: %s", robot, exc)
        with self._view_lock:
            self._asking.discard(robot)
            if replies:
                self._robots.add(robot)
                self._described += described
            else:
                self._asked[robot] = time.monotonic()

    def stop(self) -> RecorderStats:
        """Unsubscribe, write what is queued and finish the file (a valid MCAP file)."""
        for h in self._handles:
            h.close()
        self._handles = []
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join()
            self._thread = None
        with self._view_lock:  # an answer that came after the last message
            described, self._described = self._described, []
        for topic, vmsg in described:
            self._writer.write_view(topic, vmsg, time.time_ns())
        self._writer.close()
        self.stats.seconds = time.monotonic() - self._t0
        return self.stats
