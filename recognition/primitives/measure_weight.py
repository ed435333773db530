"""Measure weight primitive (thesis ch. 8): W of the held object from the wrist F/T, before/after the lift."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from contactflow.embodiments.messages import Wrench
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.recognition.messages import MeasuredWeight
from contactflow.recognition.weighing import GRAVITY, ForceAverage, average_force_z, lifted_weight


class MeasureWeight(Module):
    """Averages the vertical wrist force over ``window`` s (after ``settle`` s, so lift
    transients pass) and, given the ``baseline`` averaged before the lift, publishes the
    weight W = baseline − force as the MeasuredWeight that RecognizeObject uses.

    A task runs it twice: first in ``mode: baseline`` before the grasp, the hand free
    around the object (jaws squeezing an object on its support already carry part of its
    weight), which succeeds with the average as ``force_z`` and its ``std``; then, after
    the lift, in ``mode: weigh`` with ``baseline: ${before.force_z}`` (and ``baseline_std:
    ${before.std}``), which publishes and succeeds with ``weight`` (N), ``mass`` (kg) and
    ``std`` (N). With the default baseline 0 one weighing run trusts the sensor's tare.
    No wrench within ``timeout`` s fails.
    """

    layer = Layer.PRIMITIVE
    inputs = (Port("wrench", Wrench, "wrist F/T reading in world axes"),)
    outputs = (Port("weight", MeasuredWeight, "weight of the held object"),)
    events = (Event.SUCCESS, Event.FAILURE)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 50.0  # Hz
        arm: str = ""  # only wrenches of this arm ("" = any)
        settle: float = 0.2  # s ignored at the start (lift transients)
        window: float = 0.5  # s averaged
        min_samples: int = 5  # readings needed in the window
        mode: str = "weigh"  # "weigh": publish W against ``baseline``; "baseline": measure the force before the lift
        baseline: float = 0.0  # N, vertical force before the lift (0: the tared F/T with the hand empty)
        baseline_std: float = 0.0  # N, standard error of ``baseline``
        timeout: float = 3.0  # s

    def setup(self, io) -> None:
        super().setup(io)
        if self.params.mode not in ("weigh", "baseline"):
            raise ValueError(f"{self.name}.params.mode: {self.params.mode!r} is not weigh or baseline")
        if not math.isfinite(self.params.baseline):
            raise ValueError(f"{self.name}.params.baseline: must be finite, got {self.params.baseline}")

    def start(self) -> None:
        self.t0 = self.io.now
        self.io.take("wrench")
        self.forces: list[list[float]] = []

    def step(self) -> Status:
        p = self.params
        age = self.io.now - self.t0
        for w in self.io.take("wrench"):
            if p.arm and w.arm != p.arm:
                continue
            if len(w.force) != 3:
                raise ValueError(f"{self.name}: wrench.force from {w.hdr.source or 'wrench'} has {len(w.force)} values, expected 3")
            if p.settle <= age <= p.settle + p.window:
                self.forces.append(list(w.force))
        if age >= p.settle + p.window:
            avg = average_force_z(np.array(self.forces).reshape(-1, 3), f"{self.name}.wrench")
            if avg.samples >= p.min_samples:
                return self._finish(avg)
        if age >= p.timeout:
            self.io.emit(Event.FAILURE, f"{len(self.forces)} wrist wrenches within {p.timeout} s (need {p.min_samples})")
            return Status.FAILURE
        return Status.RUNNING

    def _finish(self, after: ForceAverage) -> Status:
        base = self.params.baseline
        if self.params.mode == "baseline":
            self.io.emit(Event.SUCCESS, "force before the lift",
                         {"force_z": after.force_z, "std": after.sem, "samples": float(after.samples)})
            return Status.SUCCESS
        weight, std = lifted_weight(ForceAverage(base, self.params.baseline_std, 1), after)
        self.io.publish("weight", MeasuredWeight(weight=weight, std=std))
        self.io.emit(Event.SUCCESS, f"W = {weight:.3f} N",
                     {"weight": weight, "mass": weight / GRAVITY, "std": std, "force_z": after.force_z,
                      "samples": float(after.samples)})
        return Status.SUCCESS
