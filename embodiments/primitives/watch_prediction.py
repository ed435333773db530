"""Watch prediction (thesis §5.7): a helper that raises ``prediction_mismatch`` when the robot's predictor reports one."""

from __future__ import annotations

from dataclasses import dataclass

from contactflow.embodiments.messages import MismatchKind, PredictionMismatch
from contactflow.embodiments.primitives.base import Primitive
from contactflow.nodes.keys import KeySpace
from contactflow.nodes.module import Port
from contactflow.nodes.status import Event


class WatchPrediction(Primitive):
    """Emits PREDICTION_MISMATCH for the first mismatch of ``kinds`` the robot's predictor reports while it runs.

    A task node runs it as a helper beside the primitive whose outcome the predictor watches
    (a transport that might hit an unseen obstacle) and has an edge on its event to a
    correction (stop, re-perceive, regrasp, re-plan). ``finish`` ends it with SUCCESS then.
    """

    events = (Event.SUCCESS, Event.FAILURE, Event.ERROR, Event.PREDICTION_MISMATCH)
    commands_arm = False
    inputs = (Port("mismatch", PredictionMismatch, "the robot's predictor's mismatches"),)

    @dataclass(frozen=True)
    class Params(Primitive.Params):
        kinds: tuple[str, ...] = ()  # the mismatch kinds to react to (unexpected_contact, missing_contact, joints, force, object); (): any
        finish: bool = False  # end with SUCCESS after the event

        def validate(self) -> None:
            known = [str(k) for k in MismatchKind]
            for k in self.kinds:
                if k not in known:
                    raise ValueError(f"kinds: {k!r} is not one of {known}")

    @classmethod
    def default_input_keys(cls, ks: KeySpace, robot: str, name: str, params: Params) -> dict[str, str]:
        """The mismatches of the predictor of the robot the module is hosted for."""
        return {"mismatch": ks.predict(robot, "mismatch")}

    def begin(self) -> None:
        self.fired = False
        if self.io is not None:
            self.io.take("mismatch")  # what the predictor said before this run is not this run's surprise

    def update(self) -> None:
        if self.io is None or self.fired:
            return
        for m in self.io.take("mismatch"):
            if m.robot != self.r.name or (self.params.kinds and str(m.kind) not in self.params.kinds):
                continue
            self.fired = True
            self.emit_once(Event.PREDICTION_MISMATCH, f"{m.kind} at t={m.since:.3f} s: {m.detail}"[:500])
            if self.params.finish:
                self.succeed(since=m.since, value=m.value)
            return
