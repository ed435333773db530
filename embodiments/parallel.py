"""Runs independent benchmark runs in worker processes, in plan order, with a progress callback."""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

RECYCLE = 25
"""Runs per worker process before the pool is replaced by fresh ones (every ``jobs * RECYCLE`` runs): a
run's simulated world is not all freed (15-70 MB a run), so 400 grasp trials in one process grew it to
16 GB. A plan up to this long with one job runs in this process."""


def _exit_with(parent: int, period: float = 1.0) -> None:
    """Worker initializer: the worker exits once ``parent`` is gone.

    A pool's workers outlive a parent that was killed (SIGTERM, SIGKILL) rather than
    interrupted: they would go on simulating, unseen, and take the cores of the next run.
    """

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(period)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="parent-watch").start()


def run_all(fn: Callable[..., dict], plan: Sequence[tuple[Any, ...]], jobs: int = 1,
            on_done: Callable[[int, dict], None] | None = None, fresh: bool = False) -> list[dict]:
    """``[fn(*args) for args in plan]``, on ``jobs`` processes; ``on_done(index, result)`` as each finishes.

    Every run builds its own simulated world, so runs share nothing; workers are spawned
    (not forked) because a forked PhysX or Vulkan context is not safe to reuse. ``fn`` must be
    a module-level function. With ``fresh`` every run gets a new process, with one job too:
    process-wide state such as OMPL's random generator (seeded once, before its first sample)
    then starts the same for a run wherever it lands, so a seeded run repeats exactly. Without it
    the workers are replaced every ``jobs *`` :data:`RECYCLE` runs, and one job runs a longer plan on workers too.
    """
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    results: list[dict | None] = [None] * len(plan)
    if jobs == 1 and not fresh and len(plan) <= RECYCLE:
        for i, args in enumerate(plan):
            results[i] = fn(*args)
            if on_done is not None:
                on_done(i, results[i])
        return [r for r in results if r is not None]
    # a pool of fresh workers per slice of the plan (Python 3.11's max_tasks_per_child above 1 can hang
    # the pool when a worker retires with runs pending, so only `fresh` uses it, at 1)
    step = len(plan) if fresh else jobs * RECYCLE
    for start in range(0, len(plan), max(step, 1)):
        with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn"),
                                 initializer=_exit_with, initargs=(os.getpid(),),
                                 max_tasks_per_child=1 if fresh else None) as pool:
            futures = {pool.submit(fn, *plan[i]): i for i in range(start, min(start + step, len(plan)))}
            for fut in as_completed(futures):
                i = futures[fut]
                results[i] = fut.result()
                if on_done is not None:
                    on_done(i, results[i])
    return [r for r in results if r is not None]


def run_logged(fn: Callable[..., dict], plan: Sequence[tuple[Any, ...]], jobs: int, log: Any, title: str,
               describe: Callable[[dict], str]) -> list[dict]:
    """:func:`run_all` with fresh processes behind a progress bar (``title``; each finished run's ``describe``),
    each run's result appended to the JSON lines file ``log`` as it finishes: a long benchmark's runs so far."""
    import json
    import pathlib

    from rich.progress import Progress as Bar

    path = pathlib.Path(log)
    path.write_text("")
    with Bar(transient=True) as bar:
        job = bar.add_task(f"{title} ({jobs} process{'es' if jobs > 1 else ''})", total=len(plan))

        def done(_: int, r: dict) -> None:
            with path.open("a") as f:
                f.write(json.dumps(r) + "\n")
            bar.update(job, advance=1, description=describe(r))

        return run_all(fn, plan, jobs, done, fresh=True)
