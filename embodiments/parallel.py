"""Runs independent benchmark runs in worker processes, in plan order, with a progress callback."""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any


def run_all(fn: Callable[..., dict], plan: Sequence[tuple[Any, ...]], jobs: int = 1,
            on_done: Callable[[int, dict], None] | None = None) -> list[dict]:
    """``[fn(*args) for args in plan]``, on ``jobs`` processes; ``on_done(index, result)`` as each finishes.

    Every run builds its own simulated world, so runs share nothing; workers are spawned
    (not forked) because a forked PhysX or Vulkan context is not safe to reuse. ``fn`` must be
    a module-level function.
    """
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    results: list[dict | None] = [None] * len(plan)
    if jobs == 1:
        for i, args in enumerate(plan):
            results[i] = fn(*args)
            if on_done is not None:
                on_done(i, results[i])
    else:
        with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = {pool.submit(fn, *args): i for i, args in enumerate(plan)}
            for fut in as_completed(futures):
                i = futures[fut]
                results[i] = fut.result()
                if on_done is not None:
                    on_done(i, results[i])
    return [r for r in results if r is not None]
