"""A scriptable zenoh peer for multi-host tests and benchmarks: JSON commands in, JSON lines out.

Run it anywhere a test needs an observer or an intruder (e.g. inside a network namespace)::

    python -m contactflow.deploy.probe --connect tcp/10.77.0.10:7450 [--config tool.json5]

Each stdin line is a command ``{"op": ..., "id": ...}``; every answer and observation is one
stdout line: ``{"ev": "ok"|"error"|"sample"|"alive"|"reply"|"queried", "id": ..., ...}``.
Operations: ``sub`` (key), ``alive`` (key: liveliness changes), ``put`` (key, kind: vector|
event|fused, values), ``query`` (key, cmd, params), ``queryable`` (key), ``token`` (key),
``peers``, ``quit``.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from typing import Any

from contactflow.nodes.messages import Command, ControlRequest, EventMsg, Vector
from contactflow.nodes.status import Event
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import WireError, decode_any, encode, stamp, to_builtins

_out_lock = threading.Lock()


def emit(**fields: Any) -> None:
    line = json.dumps(fields, default=str)
    with _out_lock:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()


def _sample_fields(key: str, payload: bytes) -> dict[str, Any]:
    out: dict[str, Any] = {"key": key, "recv": time.time(), "size": len(payload)}
    try:
        msg = decode_any(payload, key)
    except WireError as exc:
        out["error"] = str(exc)
        return out
    view = to_builtins(msg)
    out.update(type=msg.tag(), source=msg.hdr.source, seq=msg.hdr.seq, t_wall=msg.hdr.t_wall,
               inputs=[f"{i.source}#{i.seq}" for i in msg.hdr.inputs])
    for f in ("values", "event", "detail", "ok", "error", "state"):
        if isinstance(view, dict) and f in view:
            out[f] = view[f]
    return out


class Probe:
    def __init__(self, transport: ZenohTransport, name: str) -> None:
        self.t = transport
        self.name = name
        self.handles: list[Any] = []
        self.pubs: dict[str, Any] = {}
        self.seq: dict[str, int] = {}

    def _next(self, key: str) -> int:
        self.seq[key] = self.seq.get(key, 0) + 1
        return self.seq[key]

    def handle(self, cmd: dict[str, Any]) -> bool:
        op, cid = cmd.get("op"), cmd.get("id")
        if op == "quit":
            return False
        if op == "sub":
            self.handles.append(self.t.subscribe(cmd["key"], lambda k, p: emit(ev="sample", id=cid, **_sample_fields(k, p))))
        elif op == "alive":
            self.handles.append(self.t.watch_alive(cmd["key"], lambda k, up: emit(ev="alive", id=cid, key=k, up=up, t=time.time())))
        elif op == "put":
            key = cmd["key"]
            pub = self.pubs.get(key) or self.pubs.setdefault(key, self.t.publisher(key))
            kind = cmd.get("kind", "vector")
            values = [float(v) for v in cmd.get("values", [0.0])]
            if kind == "vector":
                msg: Any = Vector(values=values)
            else:
                msg = EventMsg(event=Event(cmd.get("event", "contact")), module=self.name,
                               values={f"v{i}": v for i, v in enumerate(values)})
            pub(encode(stamp(msg, f"{self.name}/{key.rsplit('/', 1)[-1]}", self._next(key), time.time())))
        elif op == "query":
            req = ControlRequest(cmd=Command(cmd.get("cmd", "describe")), params=cmd.get("params", {}), issuer=self.name)
            replies = self.t.query(cmd["key"], encode(req), timeout=float(cmd.get("timeout", 1.0)))
            emit(ev="reply", id=cid, replies=[_sample_fields(k, p) for k, p in replies])
        elif op == "queryable":
            def answer(key: str, payload: bytes) -> bytes:
                emit(ev="queried", id=cid, key=key)
                return encode(stamp(Vector(values=[1.0]), self.name, 0, time.time()))
            self.handles.append(self.t.queryable(cmd["key"], answer))
        elif op == "token":
            self.handles.append(self.t.token(cmd["key"]))
        elif op == "peers":
            emit(ev="peers", id=cid, count=len(list(self.t.session.info.peers_zid())))
        else:
            raise ValueError(f"unknown op {op!r}")
        emit(ev="ok", id=cid, op=op)
        return True


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connect", action="append", default=[])
    ap.add_argument("--listen", action="append", default=[])
    ap.add_argument("--config", default=None, help="zenoh JSON5 settings (TLS, auth)")
    ap.add_argument("--name", default="probe")
    args = ap.parse_args(argv)
    settings = ZenohSettings(mode="peer", connect=tuple(args.connect), listen=tuple(args.listen), config_file=args.config)
    try:
        t = ZenohTransport(settings, guard=False).open()  # it probes the network's enforcement, so it sends anyway
    except Exception as exc:  # a refused configuration is an observation, not a crash
        emit(ev="fatal", error=f"{type(exc).__name__}: {exc}")
        return 1
    probe = Probe(t, args.name)
    emit(ev="ready", name=args.name)
    try:
        for line in sys.stdin:
            if not line.strip():
                continue
            cmd: dict[str, Any] = {}
            try:
                cmd = json.loads(line)
                if not probe.handle(cmd):
                    break
            except Exception as exc:
                emit(ev="error", id=cmd.get("id"), error=f"{type(exc).__name__}: {exc}")
    finally:
        for h in probe.handles:
            h.close()
        t.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
