"""Transports under the module host: zenoh sessions for deployments, and an in-process bus.

The host talks bytes and key expressions only; ``ZenohTransport`` maps that onto one zenoh
session, ``LocalTransport`` onto Python callbacks (lockstep runs and tests). Both use zenoh's
own key-expression matching, so wildcards behave the same.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import zenoh

from contactflow.nodes.acl import AccessRules

Callback = Callable[[str, bytes], None]
Handler = Callable[[str, bytes], bytes]
AliveCallback = Callable[[str, bool], None]


class Handle(Protocol):
    def close(self) -> None: ...


class Transport(Protocol):
    def publisher(self, key: str, reliable: bool = True) -> Callable[[bytes], None]: ...
    def subscribe(self, keyexpr: str, callback: Callback) -> Handle: ...
    def queryable(self, key: str, handler: Handler) -> Handle: ...
    def query(self, keyexpr: str, payload: bytes, timeout: float = 2.0) -> list[tuple[str, bytes]]: ...
    def token(self, key: str) -> Handle: ...
    def alive(self, keyexpr: str, timeout: float = 1.0) -> list[str]: ...
    def watch_alive(self, keyexpr: str, callback: AliveCallback) -> Handle: ...
    def close(self) -> None: ...


LOOPBACK_ANY_PORT = "tcp/127.0.0.1:0"
ZENOH_LOG = "warn,zenoh::net::runtime::orchestrator=error"  # unless RUST_LOG says otherwise
# A node process's log also names each transport with a peer that closes, and why (a read error, an expired
# lease, a peer that stopped reading): a liveliness token that drops or a message that never came follows one.
# Not a tool's: its own session's close would print them at every exit.
NODE_ZENOH_LOG = (f"{ZENOH_LOG},zenoh_transport::unicast::universal::link=debug,"
                  "zenoh_transport::unicast::universal::transport=debug")


@dataclass(frozen=True)
class ZenohSettings:
    """How a node joins the zenoh network (a deployment manifest fills these per host)."""

    mode: str = "peer"  # peer | client | router
    listen: tuple[str, ...] = ()  # a peer without endpoints (and no config file) listens on loopback only
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    config_file: str | None = None  # a zenoh JSON5 file (TLS, auth, access control), applied first

    def to_config(self) -> zenoh.Config:
        if self.mode not in ("peer", "client", "router"):
            raise ValueError(f"zenoh.mode={self.mode!r}: expected peer, client or router")
        conf = zenoh.Config.from_file(self.config_file) if self.config_file else zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        listen = list(self.listen)
        if not listen and self.mode == "peer" and not self.config_file:
            listen = [LOOPBACK_ANY_PORT]  # zenoh's own default listens on every interface
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(listen))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        return conf


class _Closer:
    def __init__(self, fn: Callable[[], None]) -> None:
        self._fn: Callable[[], None] | None = fn

    def close(self) -> None:
        fn, self._fn = self._fn, None
        if fn is not None:
            fn()


class ZenohTransport:
    """One zenoh session; every callback runs on zenoh's threads."""

    def __init__(self, settings: ZenohSettings | None = None, guard: bool = True) -> None:
        """``guard``: refuse at once (``nodes.acl.AccessDenied``) a query the site's access rules refuse
        this session, instead of letting it time out unanswered (off only for tools that probe
        the network's enforcement itself)."""
        self.settings = settings or ZenohSettings()
        self.session: zenoh.Session | None = None
        self.rules: AccessRules | None = None
        self._guard = guard

    def open(self) -> ZenohTransport:
        # warnings too: a transport zenoh closes (a peer that stopped reading for 5 s, a lease that
        # expired) loses messages and liveliness, and the node's log must say so; the scouting
        # warning is not one (nodes connect by endpoints)
        zenoh.init_log_from_env_or(ZENOH_LOG)
        self.session = zenoh.open(self.settings.to_config())
        if self._guard and self.settings.config_file:
            self.rules = AccessRules.load(self.settings.config_file)
        return self

    def settle(self, quiet: float = 0.3, limit: float = 3.0) -> int:
        """Wait until peer discovery (gossip) stops adding peers; returns the peer count.

        A fresh peer reaches the endpoint it connects to at once and the rest of the mesh a
        little later; a tool that queries right away would miss those peers' answers.
        """
        end = time.monotonic() + limit
        count, since = -1, time.monotonic()
        while time.monotonic() < end:
            now = len(list(self._s.info.peers_zid()))
            if now != count:
                count, since = now, time.monotonic()
            elif time.monotonic() - since >= quiet:
                break
            time.sleep(0.05)
        return count

    @property
    def _s(self) -> zenoh.Session:
        if self.session is None:
            raise RuntimeError("ZenohTransport used before open()")
        return self.session

    def publisher(self, key: str, reliable: bool = True) -> Callable[[bytes], None]:
        pub = self._s.declare_publisher(
            key,
            congestion_control=zenoh.CongestionControl.BLOCK if reliable else zenoh.CongestionControl.DROP,
            reliability=zenoh.Reliability.RELIABLE if reliable else zenoh.Reliability.BEST_EFFORT,
        )
        return pub.put

    def subscribe(self, keyexpr: str, callback: Callback) -> Handle:
        # Called on the thread that receives the sample (a session's own puts: the putting thread),
        # not on a thread per subscriber: samples of one link then reach every subscriber in the
        # order they were sent, which lockstep runs rely on (a tick's commands before its ack).
        # Callbacks only decode and queue, so the network thread is never held long.
        sub = self._s.declare_subscriber(
            keyexpr, zenoh.handlers.Callback(lambda s: callback(str(s.key_expr), s.payload.to_bytes()), indirect=False)
        )
        return _Closer(sub.undeclare)

    def queryable(self, key: str, handler: Handler) -> Handle:
        # A plain callable becomes zenoh-python's indirect callback: queries are answered on a thread
        # of this queryable's own, in arrival order, so a slow handler (a translation, a dispatch that
        # queries the robots) never holds zenoh's network threads.
        def on_query(q: zenoh.Query) -> None:
            payload = q.payload.to_bytes() if q.payload is not None else b""
            # reply on the declared key: a wildcard query then tells the answerers apart
            q.reply(key, handler(key, payload))

        qbl = self._s.declare_queryable(key, on_query)
        return _Closer(qbl.undeclare)

    def query(self, keyexpr: str, payload: bytes, timeout: float = 2.0) -> list[tuple[str, bytes]]:
        if self.rules is not None:
            self.rules.check("query", keyexpr)
        out = []
        for reply in self._s.get(keyexpr, payload=payload, timeout=timeout):
            if reply.ok is not None:
                out.append((str(reply.ok.key_expr), reply.ok.payload.to_bytes()))
        return out

    def token(self, key: str) -> Handle:
        tok = self._s.liveliness().declare_token(key)
        return _Closer(tok.undeclare)

    def alive(self, keyexpr: str, timeout: float = 1.0) -> list[str]:
        return [str(r.ok.key_expr) for r in self._s.liveliness().get(keyexpr, timeout=timeout) if r.ok]

    def watch_alive(self, keyexpr: str, callback: AliveCallback) -> Handle:
        sub = self._s.liveliness().declare_subscriber(
            keyexpr,
            lambda s: callback(str(s.key_expr), s.kind == zenoh.SampleKind.PUT),
            history=True,
        )
        return _Closer(sub.undeclare)

    def close(self) -> None:
        s, self.session = self.session, None
        if s is not None:
            s.close()


def key_matches(pattern: str, key: str) -> bool:
    """Whether key expressions ``pattern`` and ``key`` share a key (zenoh's intersection)."""
    return zenoh.KeyExpr(pattern).intersects(zenoh.KeyExpr(key))


@dataclass(eq=False)  # one bus is one bus (hashable by identity: the robot links are kept per transport)
class LocalTransport:
    """In-process bus with zenoh semantics; delivery is synchronous (deterministic)."""

    subs: list[tuple[str, Callback]] = field(default_factory=list)
    queryables: list[tuple[str, Handler]] = field(default_factory=list)
    tokens: dict[int, str] = field(default_factory=dict)
    watchers: list[tuple[str, AliveCallback]] = field(default_factory=list)
    _lock: threading.RLock = field(default_factory=threading.RLock)
    _next: int = 0

    def publisher(self, key: str, reliable: bool = True) -> Callable[[bytes], None]:
        def put(data: bytes) -> None:
            with self._lock:
                targets = [cb for pat, cb in self.subs if key_matches(pat, key)]
            for cb in targets:
                try:
                    cb(key, bytes(data))
                except Exception:  # as in zenoh, a failing subscriber never reaches the publisher
                    logging.getLogger("contactflow.transport").exception("subscriber of %s raised", key)
        return put

    def _remove(self, table: list, entry: object) -> Callable[[], None]:
        def close() -> None:
            with self._lock:
                if entry in table:
                    table.remove(entry)
        return close

    def subscribe(self, keyexpr: str, callback: Callback) -> Handle:
        entry = (keyexpr, callback)
        with self._lock:
            self.subs.append(entry)
        return _Closer(self._remove(self.subs, entry))

    def queryable(self, key: str, handler: Handler) -> Handle:
        entry = (key, handler)
        with self._lock:
            self.queryables.append(entry)
        return _Closer(self._remove(self.queryables, entry))

    def query(self, keyexpr: str, payload: bytes, timeout: float = 2.0) -> list[tuple[str, bytes]]:
        with self._lock:
            targets = [(k, h) for k, h in self.queryables if key_matches(keyexpr, k)]
        return [(k, h(k, payload)) for k, h in targets]

    def token(self, key: str) -> Handle:
        with self._lock:
            self._next += 1
            tid = self._next
            self.tokens[tid] = key
            watchers = [cb for pat, cb in self.watchers if key_matches(pat, key)]
        for cb in watchers:
            cb(key, True)

        def close() -> None:
            with self._lock:
                k = self.tokens.pop(tid, None)
                targets = [cb for pat, cb in self.watchers if k is not None and key_matches(pat, k)]
            for cb in targets:
                cb(key, False)
        return _Closer(close)

    def alive(self, keyexpr: str, timeout: float = 1.0) -> list[str]:
        with self._lock:
            return sorted({k for k in self.tokens.values() if key_matches(keyexpr, k)})

    def watch_alive(self, keyexpr: str, callback: AliveCallback) -> Handle:
        entry = (keyexpr, callback)
        with self._lock:
            self.watchers.append(entry)
            existing = [k for k in self.tokens.values() if key_matches(keyexpr, k)]
        for k in existing:
            callback(k, True)
        return _Closer(self._remove(self.watchers, entry))

    def close(self) -> None:
        with self._lock:
            self.subs.clear()
            self.queryables.clear()


