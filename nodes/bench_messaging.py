"""``contactflow bench messaging``: our typed messaging vs raw zenoh-python, two processes.

Per payload size (64 B, 4 KiB, 64 KiB, 1 MiB) and for both stacks in the same run: throughput
(messages per second received by the other process, publisher back-pressured by zenoh's
BLOCK congestion control) and one-way latency p50/p99 at a paced rate. "contactflow" means a
typed :class:`~contactflow.nodes.messages.Array` message stamped with its header, encoded,
published, then decoded and validated on the receiving side, exactly as a module input.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Array
from contactflow.nodes.procs import free_port
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import NDArray, WireError, decode, encode, stamp

SIZES = {"64B": 64, "4KiB": 4 << 10, "64KiB": 64 << 10, "1MiB": 1 << 20}
COUNTS = {"64B": 20000, "4KiB": 20000, "64KiB": 4000, "1MiB": 300}
LATENCY_COUNT = 400
STACKS = ("raw", "contactflow")


ROUNDS = 3  # each case runs this often, the stacks interleaved; the median is reported
KS = KeySpace("bench")


def _key(stack: str, size: str, phase: str, rnd: int = 0) -> str:
    return KS.bench(stack, size, phase, str(rnd))


def subscriber(port: int) -> None:
    """The receiving process: records arrivals per key, prints JSON stats on the done signal.

    It connects to the publisher, which listens before starting it: a peer that connects
    before the other side listens is only retried with a growing back-off (tens of seconds).
    """
    t = ZenohTransport(ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",))).open()
    stats: dict[str, dict] = {}
    done = threading.Event()
    lock = threading.Lock()

    def record(key: str, sent_ns: int, now: int) -> None:
        with lock:
            s = stats.setdefault(key, {"n": 0, "first": now, "last": now, "lat": []})
            s["n"] += 1
            s["last"] = now
            s["lat"].append((now - sent_ns) / 1e3)

    def on_raw(sample: zenoh.Sample) -> None:
        now = time.time_ns()
        payload = sample.payload.to_bytes()
        record(str(sample.key_expr), int.from_bytes(payload[:8], "little"), now)

    def on_ours(key: str, payload: bytes) -> None:
        now = time.time_ns()
        try:
            msg = decode(payload, Array, key)
        except WireError:
            return
        record(key, int(msg.hdr.t_wall * 1e9), now)

    raw_sub = t.session.declare_subscriber(KS.bench("raw"), on_raw)
    # held until the end: a dropped liveliness token is withdrawn at once
    handles = [t.subscribe(KS.bench("contactflow"), on_ours),
               t.subscribe(KS.bench_signal("done"), lambda _k, _p: done.set()),
               t.token(KS.bench_signal("ready"))]
    done.wait(600)
    out = {}
    for key, s in stats.items():
        lat = np.array(s["lat"])
        dur = (s["last"] - s["first"]) / 1e9
        out[key] = {"n": s["n"], "rate": (s["n"] - 1) / dur if dur > 0 else 0.0,
                    "p50_us": float(np.percentile(lat, 50)), "p99_us": float(np.percentile(lat, 99))}
    print(json.dumps(out), flush=True)
    raw_sub.undeclare()
    for h in handles:
        h.close()
    t.close()


def _send(t: ZenohTransport, stack: str, size_name: str, phase: str, count: int, paced: bool, rnd: int) -> None:
    size = SIZES[size_name]
    key = _key(stack, size_name, phase, rnd)
    if stack == "raw":
        pub = t.session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK).put
    else:
        pub = t.publisher(key)
    body = np.random.default_rng(0).integers(0, 255, size, dtype=np.uint8)
    buf = bytearray(body.tobytes())  # built once: the baseline pays only zenoh's own copy per message
    for i in range(count):
        if stack == "raw":
            buf[:8] = time.time_ns().to_bytes(8, "little")  # stamped when sent, as our header is
            pub(buf)
        else:
            msg = stamp(Array(array=NDArray.of(body)), "bench/pub/out", i + 1, 0.0)
            pub(encode(msg))
        if paced:
            time.sleep(0.002 if size < (64 << 10) else 0.01)


def run(out_dir: Path, quick: bool = False) -> dict:
    console = Console()
    port = free_port()
    t = ZenohTransport(ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",))).open()
    sub = subprocess.Popen([sys.executable, "-m", "contactflow.nodes.bench_messaging", "sub", str(port)],
                           stdout=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        while not t.alive(KS.bench_signal("ready")):
            if time.monotonic() > deadline or sub.poll() is not None:
                raise RuntimeError(f"the benchmark's subscriber process did not come up (exit code {sub.poll()})")
            time.sleep(0.1)
        scale = 10 if quick else 1
        rounds = 1 if quick else ROUNDS
        cases = [(size, rnd, stack) for size in SIZES for rnd in range(rounds) for stack in STACKS]
        with Progress(console=console, transient=True) as progress:
            task = progress.add_task("messaging", total=len(cases))
            for size, rnd, stack in cases:
                progress.update(task, description=f"{stack} {size} round {rnd + 1}")
                _send(t, stack, size, "tput", max(COUNTS[size] // scale, 20), paced=False, rnd=rnd)
                time.sleep(0.2)
                n_lat = max(LATENCY_COUNT // scale, 20) if SIZES[size] < (1 << 20) else max(100 // scale, 20)
                _send(t, stack, size, "lat", n_lat, paced=True, rnd=rnd)
                time.sleep(0.2)
                progress.advance(task)
        t.publisher(KS.bench_signal("done"))(b"")
        line, _ = sub.communicate(timeout=120)
    finally:
        t.close()
        if sub.poll() is None:
            sub.kill()
    stats = json.loads(line.strip().splitlines()[-1])

    def med(stack: str, size: str, phase: str, field: str) -> float:
        vals = [stats[k][field] for k in (_key(stack, size, phase, r) for r in range(rounds)) if k in stats]
        return float(np.median(vals)) if vals else 0.0

    rows = []
    for size in SIZES:
        raw_rate, cf_rate = med("raw", size, "tput", "rate"), med("contactflow", size, "tput", "rate")
        raw_p99, cf_p99 = med("raw", size, "lat", "p99_us"), med("contactflow", size, "lat", "p99_us")
        rows.append({
            "payload": size, "rounds": rounds,
            "raw_msgs_per_s": raw_rate, "cf_msgs_per_s": cf_rate,
            "throughput_ratio": cf_rate / raw_rate if raw_rate else 0.0,
            "raw_p50_us": med("raw", size, "lat", "p50_us"), "cf_p50_us": med("contactflow", size, "lat", "p50_us"),
            "raw_p99_us": raw_p99, "cf_p99_us": cf_p99,
            "p99_ratio": cf_p99 / raw_p99 if raw_p99 else 0.0,
        })
    table = Table(title=f"contactflow messaging vs raw zenoh-python (2 processes, loopback, median of {rounds})")
    for col in ("payload", "raw msg/s", "cf msg/s", "ratio", "raw p50 µs", "cf p50 µs", "raw p99 µs",
                "cf p99 µs", "p99 ratio"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(r["payload"], f"{r['raw_msgs_per_s']:,.0f}", f"{r['cf_msgs_per_s']:,.0f}",
                      f"{r['throughput_ratio']:.2f}", f"{r['raw_p50_us']:.0f}", f"{r['cf_p50_us']:.0f}",
                      f"{r['raw_p99_us']:.0f}", f"{r['cf_p99_us']:.0f}", f"{r['p99_ratio']:.2f}")
    console.print(table)
    summary = {"benchmark": "messaging", "quick": quick, "goal": {"throughput_ratio": ">= 0.8", "p99_ratio": "<= 1.5"},
               "rows": rows}
    (out_dir / "messaging.json").write_text(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    subscriber(int(sys.argv[2]))
