"""Suite-wide order and locks on several workers: the heavy tests first, and tests marked ``exclusive`` last and alone."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import pytest


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "heavy: one of the suite's longest tests, started early so no worker ends alone on it")
    config.addinivalue_line(
        "markers", "exclusive: runs while no other test runs (its assertions compare wall-clock-sensitive runs, "
                   "e.g. a lockstep run repeated across process layouts, which CPU contention can reorder)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The heavy tests first and the exclusive ones last (a worker's test file goes with them): the short
    tests between let the two workers end together, and an exclusive test waits for the other worker's
    current test, short at the end (behind the demo it would wait two minutes)."""
    items.sort(key=lambda item: (item.get_closest_marker("heavy") is None)
               + 2 * (item.get_closest_marker("exclusive") is not None))


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
