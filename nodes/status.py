"""The one documented enum of module states and primitive step outcomes, and the event labels.

``Status`` is what a module's ``step`` returns and what a module publishes as its state.
``Event`` is the label of every event message: primitive outcomes (the edges of a task
graph, thesis §3.2), contact events from fusion (§4.6) and hardware faults. Both travel on
the wire as their lower-case string value so that any msgpack client can read them.
"""

from __future__ import annotations

from enum import StrEnum


class Status(StrEnum):
    """Lifecycle state of a module, and the outcome of one ``step``.

    ``step`` returns RUNNING while the controller still works, SUCCESS or FAILURE when a
    primitive reached its goal or gave up (a task then follows the matching edge). IDLE and
    STOPPED are states a module is put in by control messages; ERROR means the module raised
    and was stopped by its host.
    """

    IDLE = "idle"
    RUNNING = "running"
    SUCCESS = "success"
    FAILURE = "failure"
    STOPPED = "stopped"
    ERROR = "error"

    @property
    def finished(self) -> bool:
        return self in (Status.SUCCESS, Status.FAILURE, Status.ERROR)


class Event(StrEnum):
    """Every event label the system emits (thesis Tables 3.1-3.2, 7.2 and ch. 4).

    Primitive outcomes: SUCCESS, FAILURE, ERROR, TIMEOUT.
    Contact events: CONTACT (a primitive saw a contact it waited for), CONTACT_MADE and
    CONTACT_BROKEN (fusion's condensed contacts appearing/disappearing), GRASP_STABLE,
    GRASP_LOST, OBJECT_LOST.
    Perception: OBJECT_DETECTED, OBJECT_NOT_FOUND, MOTION_DETECTED.
    Robot: HARDWARE_FAILURE (physics blow-up, stuck joint, lost sensor stream, a controller
    gone or stalled), STUCK, OVERRUN (a lockstep node answered a world tick after its deadline).
    Prediction: PREDICTION_MISMATCH (simulated and sensed events disagree, §5.7).
    """

    SUCCESS = "success"
    FAILURE = "failure"
    ERROR = "error"
    TIMEOUT = "timeout"
    CONTACT = "contact"
    CONTACT_MADE = "contact_made"
    CONTACT_BROKEN = "contact_broken"
    GRASP_STABLE = "grasp_stable"
    GRASP_LOST = "grasp_lost"
    OBJECT_LOST = "object_lost"
    OBJECT_DETECTED = "object_detected"
    OBJECT_NOT_FOUND = "object_not_found"
    MOTION_DETECTED = "motion_detected"
    HARDWARE_FAILURE = "hardware_failure"
    STUCK = "stuck"
    OVERRUN = "overrun"
    PREDICTION_MISMATCH = "prediction_mismatch"


STATUS_EVENT = {
    Status.SUCCESS: Event.SUCCESS,
    Status.FAILURE: Event.FAILURE,
    Status.ERROR: Event.ERROR,
}
"""The event a module emits when its step finishes with that status."""
