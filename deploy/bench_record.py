"""Benchmark: recording 10,000 small messages/s plus 30 Hz 640x480 depth frames, and replaying the file.

Three processes: the recorder (``Recorder`` on its own zenoh session, as ``contactflow record``
runs), a publisher of the load (sequence-numbered, so the file's losses are counted, not
guessed) and this one. Measured: messages the file lacks (goal 0), the recorder's CPU share
of one core and peak RSS, the file's size, and the replay's speed (x real time) when it
publishes as fast as it can.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from contactflow.deploy.recorder import Recorder
from contactflow.deploy.recording import Recording
from contactflow.deploy.replayer import Replayer
from contactflow.embodiments.messages import DepthImage
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.messages import Vector
from contactflow.nodes.procs import free_port
from contactflow.nodes.transport import ZenohSettings, ZenohTransport
from contactflow.nodes.wire import encode, stamp

console = Console()
SITE = "benchrec"
KS = KeySpace(SITE)
SMALL_KEY = KS.output("bench", "pub", "src", "small")
DEPTH_KEY = KS.robot("bench", "depth")


def _publisher(endpoint: str, seconds: float, rate: float, depth_hz: float, report: Path) -> None:
    """Publish the load for ``seconds`` and write what was sent."""
    t = ZenohTransport(ZenohSettings(connect=(endpoint,))).open()
    small, depth = t.publisher(SMALL_KEY), t.publisher(DEPTH_KEY)
    time.sleep(1.0)  # the recorder's subscription reaches this session
    rng = np.random.default_rng(0)
    frame = rng.uniform(0.3, 2.0, (480, 640)).astype(np.float32)
    K = np.array([[525.0, 0, 320], [0, 525.0, 240], [0, 0, 1]])
    sent = {"small": 0, "depth": 0}
    t0 = time.monotonic()

    def frames() -> None:
        k = 0
        while time.monotonic() < t0 + seconds:
            k += 1
            msg = stamp(DepthImage.of(frame, K, np.eye(4)), "bench/pub/camera", k, time.time())
            depth(encode(msg))
            sent["depth"] = k
            time.sleep(max(0.0, t0 + k / depth_hz - time.monotonic()))
    th = threading.Thread(target=frames, daemon=True)
    th.start()
    n = 0
    while (elapsed := time.monotonic() - t0) < seconds:
        due = int(elapsed * rate)
        while n < due:
            n += 1
            small(encode(stamp(Vector(values=[float(n), 1.0, 2.0]), "bench/pub/src", n, time.time())))
        time.sleep(0.0005)
    sent["small"] = n
    th.join()
    sent["seconds"] = time.monotonic() - t0
    report.write_text(json.dumps(sent))
    t.close()


def _recorder(listen: str, path: Path, report: Path) -> None:
    """Record until SIGINT, then write the recorder's counts and this process's CPU time and peak RSS."""
    t = ZenohTransport(ZenohSettings(listen=(listen,))).open()
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    rec = Recorder(t, [f"{KS.prefix}/**"], path, SITE, view=True).start()
    c0 = resource.getrusage(resource.RUSAGE_SELF)
    w0 = time.monotonic()
    print("ready", flush=True)
    stop.wait()
    stats = rec.stop()
    c1 = resource.getrusage(resource.RUSAGE_SELF)
    wall = time.monotonic() - w0
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    report.write_text(json.dumps({**stats.as_dict(), "cpu_s": cpu, "wall_s": wall, "peak_rss_mb": c1.ru_maxrss / 1024}))
    t.close()


def _child(role: str, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "contactflow.deploy.bench_record", role, *args],
                            stdout=subprocess.PIPE, text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))


def run(out_dir: Path, quick: bool = False) -> dict:
    seconds = 5.0 if quick else 60.0
    rate, depth_hz = 10_000.0, 30.0
    out_dir = Path(out_dir)
    path = out_dir / "record_bench.mcap"
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    console.print(f"recording {rate:,.0f} small messages/s + {depth_hz:g} Hz 640x480 depth frames for {seconds:g} s")
    rec = _child("recorder", endpoint, str(path), str(out_dir / "recorder.json"))
    assert rec.stdout is not None
    if rec.stdout.readline().strip() != "ready":
        rec.kill()
        raise RuntimeError("the recorder did not start")
    pub = _child("publisher", endpoint, str(seconds), str(rate), str(depth_hz), str(out_dir / "publisher.json"))
    pub.wait(timeout=seconds + 120)
    time.sleep(1.0)  # what is in flight reaches the recorder
    rec.send_signal(signal.SIGINT)
    rec.wait(timeout=300)
    sent = json.loads((out_dir / "publisher.json").read_text())
    got = json.loads((out_dir / "recorder.json").read_text())
    recording = Recording.open(path)
    in_file = {"small": recording.counts.get(SMALL_KEY, 0), "depth": recording.counts.get(DEPTH_KEY, 0)}
    missing = {k: sent[k] - in_file[k] for k in in_file}

    console.print("replaying it as fast as it goes")
    tool = ZenohTransport(ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",))).open()
    try:
        stats = Replayer(tool, recording, site="benchreplay", rate=0).run()
    finally:
        tool.close()
    summary = {
        "benchmark": "record", "seconds": seconds, "rate_hz": rate, "depth_hz": depth_hz,
        "sent": sent, "recorded": in_file, "missing": missing, "missing_total": sum(missing.values()),
        "recorder": got, "cpu_share": got["cpu_s"] / got["wall_s"], "peak_rss_mb": got["peak_rss_mb"],
        "file_mb": path.stat().st_size / 1e6, "view_messages": got["view"],
        "replay": stats.as_dict(),
    }
    table = Table(title=f"Recording {rate:,.0f} msg/s + {depth_hz:g} Hz 640x480 depth for {seconds:g} s")
    for col in ("measure", "value", "goal"):
        table.add_column(col)
    table.add_row("small messages sent / in the file", f"{sent['small']:,} / {in_file['small']:,}", "all")
    table.add_row("depth frames sent / in the file", f"{sent['depth']:,} / {in_file['depth']:,}", "all")
    table.add_row("missing (queue drops + lost)", f"{summary['missing_total']:,} ({got['dropped']:.0f} dropped)", "0")
    table.add_row("recorder CPU (share of one core)", f"{summary['cpu_share']:.0%}", "")
    table.add_row("recorder peak RSS", f"{summary['peak_rss_mb']:.0f} MB", "")
    table.add_row("file size", f"{summary['file_mb']:.0f} MB", "")
    table.add_row("replay speed (as fast as it goes)", f"{stats.speed:.2f}x real time ({stats.messages:,} messages)", "")
    console.print(table)
    (out_dir / "record.json").write_text(json.dumps(summary, indent=2))
    path.unlink()  # gigabytes of benchmark load: the numbers are kept, the file is not
    return summary


def main(argv: list[str]) -> int:
    role, *args = argv
    if role == "publisher":
        endpoint, seconds, rate, depth_hz, report = args
        _publisher(endpoint, float(seconds), float(rate), float(depth_hz), Path(report))
    elif role == "recorder":
        listen, path, report = args
        _recorder(listen, Path(path), Path(report))
    else:
        raise SystemExit(f"unknown role {role!r}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
