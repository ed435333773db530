"""Suite-wide order on several workers: the heavy test files first, the longest first."""

from __future__ import annotations

import pytest


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "heavy(seconds): one of the suite's longest tests (its file runs about ``seconds`` "
                                       "on two workers), started early, longest file first, so no worker ends alone on it")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The heavy tests first, longest first (a worker's test file goes with them; ``--no-loadscope-reorder``
    keeps xdist from ordering the files by their number of tests instead): the short tests after them let
    the two workers end together."""
    def key(item: pytest.Item) -> tuple[bool, float]:
        heavy = item.get_closest_marker("heavy")
        return heavy is None, -float(heavy.kwargs.get("seconds", 0.0)) if heavy else 0.0

    items.sort(key=key)
