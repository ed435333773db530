"""Shared simulated scenes for the embodiment tests (module scope keeps the suite fast)."""

from __future__ import annotations

import pytest

from contactflow.embodiments.sim_robot import SimRobot
from contactflow.embodiments.testing import make_robot


@pytest.fixture(scope="module")
def melfa() -> SimRobot:
    return make_robot("melfa")
