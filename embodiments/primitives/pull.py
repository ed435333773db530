"""Pull (§6.3.6): the push primitive moving against ``direction`` (toward the robot for the default)."""

from __future__ import annotations

from contactflow.embodiments.primitives.push import Push


class Pull(Push):
    """Pull back along ``-direction`` by ``distance`` with the same force limit as push."""

    sign = -1.0
