"""Baxter's home (App. A.4): its spec, translation factory and the primitive overrides its hardware needs."""

from __future__ import annotations

from contactflow.embodiments.registry import RobotHome
from contactflow.embodiments.robots.baxter.spec import SPEC

HOME = RobotHome(
    spec=SPEC,
)
