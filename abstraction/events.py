"""Abstract events (thesis Table 7.2): the labels of ATD transitions."""

from __future__ import annotations

from enum import StrEnum


class AbstractEvent(StrEnum):
    """Embodiment-independent events; each factory detects them with its own sensors."""

    SUCCESS = "success"  # primitive successfully completed
    GRASP_STABLE = "grasp_stable"  # stable grasp detected
    GRASP_LOST = "grasp_lost"  # grasp loss detected
    TIMEOUT = "timeout"  # timeout for specified time
    HARDWARE_FAILURE = "hardware_failure"  # hardware failure detected
    ERROR = "error"  # generic error
    PREDICTION_MISMATCH = "prediction_mismatch"  # the robot's prediction and its sensing disagree (thesis §5.7; not in Table 7.2)

    @property
    def needs_grasp_sensing(self) -> bool:
        return self in (AbstractEvent.GRASP_STABLE, AbstractEvent.GRASP_LOST)
