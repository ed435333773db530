"""Benchmark runs on worker processes: results in plan order, progress per run, bad job counts refused."""

from __future__ import annotations

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


def test_a_job_count_below_one_is_refused() -> None:
    with pytest.raises(ValueError, match="jobs must be >= 1, got 0"):
        run_all(dict, PLAN, jobs=0)
