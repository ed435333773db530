"""The node process: one zenoh session hosting the modules a configuration names."""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
from pathlib import Path

import zenoh

from contactflow.nodes.config import NodeConfig, load_node_config
from contactflow.nodes.host import ModuleHost
from contactflow.nodes.transport import NODE_ZENOH_LOG, ZenohTransport


class Node:
    """Lifecycle of one node: open the session, host the modules, run, shut down cleanly."""

    def __init__(self, config: NodeConfig) -> None:
        self.config = config
        self.transport = ZenohTransport(config.zenoh)
        self.host: ModuleHost | None = None
        self.stopped = threading.Event()

    def start(self) -> ModuleHost:
        self.transport.open()
        self.host = ModuleHost(self.config, self.transport)
        for mc in self.config.modules:
            self.host.add(mc)
        self.host.start()
        return self.host

    def stop(self) -> None:
        if self.host is not None:
            self.host.shutdown()
        self.transport.close()
        self.stopped.set()


def run_node(path: str | Path) -> None:
    """Run a node until SIGINT or SIGTERM."""
    config = load_node_config(path)
    if not sys.stdout.isatty():
        # a log file or a pipe gets plain text: zenoh colours its lines (transports closed) wherever they go
        os.environ.setdefault("NO_COLOR", "1")
    zenoh.init_log_from_env_or(NODE_ZENOH_LOG)  # before the session's own (the first one counts)
    node = Node(config)
    quit_ = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        logging.getLogger("contactflow").info("node %s: signal %d, shutting down", config.node, signum)
        quit_.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    try:
        node.start()
        logging.getLogger("contactflow").info(
            "node %s up (site %s, %d modules, clock %s)", config.node, config.site, len(config.modules), config.clock
        )
        while not quit_.wait(0.2):
            if node.host is not None and node.host.dead.is_set():
                break
    finally:
        # whatever ends the main thread (a module's setup that raised, a log whose pipe broke) stops the loop
        # too: left running, it kept the process alive, its world ticking, after the node was gone
        node.stop()
    if node.host is not None and node.host.dead.is_set():
        raise SystemExit(1)  # the loop died: a supervisor restarts the node
