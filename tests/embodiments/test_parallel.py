"""Benchmark runs on worker processes: results in plan order, progress per run, bad job counts refused, no orphans."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from contactflow.embodiments.parallel import run_all

# builtins pickle by name, so a spawned worker can run them without importing the tests
PLAN = [([("run", k), ("square", k * k)],) for k in range(5)]


@pytest.mark.parametrize("jobs", [1, 2])
def test_results_come_back_in_plan_order_with_one_callback_per_run(jobs: int) -> None:
    seen: list[int] = []
    out = run_all(dict, PLAN, jobs=jobs, on_done=lambda i, r: seen.append(i) or None)
    assert out == [{"run": k, "square": k * k} for k in range(5)]
    assert sorted(seen) == list(range(5))


@pytest.mark.parametrize("jobs", [1, 2])
def test_fresh_runs_each_get_a_process_of_their_own(jobs: int) -> None:
    pids = run_all(os.getpid, [()] * 3, jobs=jobs, fresh=True)
    assert len(set(pids)) == 3 and os.getpid() not in pids
    assert run_all(os.getpid, [()] * 2, jobs=1) == [os.getpid()] * 2  # without fresh, one job runs in this process


def test_a_worker_is_replaced_after_its_share_of_runs_and_a_long_plan_with_one_job_runs_on_workers() -> None:
    from contactflow.embodiments import parallel

    n = parallel.RECYCLE + 1
    pids = run_all(os.getpid, [()] * n, jobs=1)
    assert os.getpid() not in pids and len(set(pids)) == 2  # RECYCLE runs on one worker, the last on the next
    assert pids.count(pids[0]) == parallel.RECYCLE


def test_a_job_count_below_one_is_refused() -> None:
    with pytest.raises(ValueError, match="jobs must be >= 1, got 0"):
        run_all(dict, PLAN, jobs=0)


def _pool_workers(pid: int) -> set[int]:
    """The spawned pool workers among ``pid``'s children (not its resource tracker)."""
    out = set()
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            parent = int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1])
            if parent == pid and "spawn_main" in (proc / "cmdline").read_text():
                out.add(int(proc.name))
        except OSError:  # the process ended while we looked
            continue
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_workers_exit_when_the_parent_is_killed() -> None:
    code = "from contactflow.embodiments.parallel import run_all; import time; run_all(time.sleep, [(120,), (120,)], jobs=2)"
    parent = subprocess.Popen([sys.executable, "-c", code])
    workers: set[int] = set()
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            workers = _pool_workers(parent.pid)
            if len(workers) == 2:
                break
            time.sleep(0.2)
        assert len(workers) == 2, "the pool did not start its two workers"
        time.sleep(1.0)  # the workers are sleeping in their runs
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 15
        while any(_alive(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not any(_alive(w) for w in workers), "a worker outlived its killed parent"
    finally:
        for pid in [parent.pid, *workers]:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        parent.wait()
