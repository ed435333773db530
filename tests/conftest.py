"""Suite-wide order and locks on several workers: the heavy tests first, and tests marked ``exclusive`` last and alone."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import pytest


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "heavy(seconds): one of the suite's longest tests (its file runs about ``seconds`` "
                                       "on two workers), started early, longest file first, so no worker ends alone on it")
    config.addinivalue_line(
        "markers", "exclusive: runs while no other test runs (its assertions compare wall-clock-sensitive runs, "
                   "e.g. a lockstep run repeated across process layouts, which CPU contention can reorder)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The heavy tests first, longest first, and the exclusive ones last (a worker's test file goes with
    them; ``--no-loadscope-reorder`` keeps xdist from ordering the files by their number of tests instead):
    the short tests between let the two workers end together, and an exclusive test waits for the other
    worker's current test, short at the end (behind the demo it would wait two minutes)."""
    def key(item: pytest.Item) -> tuple[int, float]:
        heavy = item.get_closest_marker("heavy")
        return ((heavy is None) + 2 * (item.get_closest_marker("exclusive") is not None),
                -float(heavy.kwargs.get("seconds", 0.0)) if heavy else 0.0)

    items.sort(key=key)


@contextmanager
def _flock(path: Path, mode: int) -> Iterator[None]:
    with open(path, "a") as f:
        fcntl.flock(f, mode)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


@pytest.fixture(autouse=True)
def _exclusive(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """On xdist workers every test holds a shared lock and an ``exclusive`` test the exclusive one; a
    turnstile taken before either keeps a waiting exclusive test from being overtaken by new shared
    holders (writer preference, which flock alone does not give)."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        yield
        return
    shared = tmp_path_factory.getbasetemp().parent  # one directory for all the session's workers
    alone = request.node.get_closest_marker("exclusive") is not None
    with ExitStack() as held:
        with _flock(shared / "turnstile.lock", fcntl.LOCK_EX):
            held.enter_context(_flock(shared / "suite.lock", fcntl.LOCK_EX if alone else fcntl.LOCK_SH))
        yield
