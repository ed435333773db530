"""Recognize object primitive (LOC, thesis §8.4.3): which known object this is, or unknown."""

from __future__ import annotations

import json
import pathlib
from dataclasses import dataclass

from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.recognition.classifiers import (
    IncrementalRecognizer,
    NormalDensityClassifier,
    NSigmaClassifier,
    load_knowledge,
)
from contactflow.recognition.features import FEATURES, object_features
from contactflow.recognition.messages import (
    MeasuredWeight,
    ObjectIdentity,
    SegmentedObjects,
    provenance,
)


class RecognizeObject(Module):
    """Identifies one segmented object from its box dimensions, SOS/AOS activations and,
    when the feature set has W, the weight measured after lifting it. Confident answers
    are learnt at once (incremental learning); an unconfident one is "unknown" and ends
    with OBJECT_NOT_FOUND, never with a forced guess.

    The knowledge base is the JSON written by ``contactflow bench recognition``
    (``recognition_knowledge.json``) or a trained classifier given to the constructor.
    """

    layer = Layer.PRIMITIVE
    inputs = (Port("objects", SegmentedObjects, "segmented objects"),
              Port("weight", MeasuredWeight, "weight from the wrist F/T after lifting"))
    outputs = (Port("identity", ObjectIdentity, "object label and confidence"),)
    events = (Event.OBJECT_DETECTED, Event.OBJECT_NOT_FOUND)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 10.0  # Hz
        timeout: float = 3.0  # s waiting for the object (and its weight)
        index: int = 0  # which object (largest first)
        classifier: str = "normal_density"  # or "n_sigma" (eq. 8.5)
        n: float = 2.0  # n-sigma tolerance
        min_posterior: float = 0.9  # normal density: below this the answer is unknown
        knowledge: str = ""  # path of the knowledge base JSON
        learn: bool = True  # add confident answers to the class statistics

    def __init__(self, name: str, params: Params | None = None, classifier=None,
                 features: tuple[str, ...] = FEATURES) -> None:
        super().__init__(name, params)
        self.given = classifier
        self.features = tuple(features)

    def setup(self, io) -> None:
        super().setup(io)
        p = self.params
        if self.given is not None:
            clf = self.given
        elif p.classifier == "normal_density":
            clf = NormalDensityClassifier(min_posterior=p.min_posterior)
        elif p.classifier == "n_sigma":
            clf = NSigmaClassifier(p.n)
        else:
            raise ValueError(f"{self.name}.params.classifier: {p.classifier!r} is not normal_density or n_sigma")
        if p.knowledge:
            path = pathlib.Path(p.knowledge)
            try:
                data = json.loads(path.read_text())
            except (OSError, json.JSONDecodeError) as exc:
                raise ValueError(f"{self.name}.params.knowledge: cannot read {path}: {exc}") from None
            self.features = load_knowledge(clf, data, where=str(path))
        self.recognizer = IncrementalRecognizer(clf)

    def start(self) -> None:
        self.t0 = self.io.now
        self.io.take("objects")
        self.io.take("weight")
        self.weight: MeasuredWeight | None = None

    def step(self) -> Status:
        weights = self.io.take("weight")
        if weights:
            self.weight = weights[-1]
        needs_weight = "W" in self.features
        objs = self.io.latest("objects")
        ready = objs is not None and len(objs.objects) > self.params.index and (self.weight is not None or not needs_weight)
        if ready:
            return self._recognize(objs)
        if self.io.now - self.t0 >= self.params.timeout:
            what = "weight" if objs is not None and needs_weight else f"object {self.params.index}"
            self.io.emit(Event.OBJECT_NOT_FOUND, f"no {what} within {self.params.timeout} s")
            return Status.FAILURE
        return Status.RUNNING

    def _recognize(self, objs: SegmentedObjects) -> Status:
        box = objs.objects[self.params.index].box.box()
        w = self.weight.weight if self.weight is not None else float("nan")
        x = object_features(box.extent, w, self.features)
        pred = self.recognizer.observe(x) if self.params.learn else self.recognizer.classifier.classify(x)
        label = "unknown" if pred.label is None else str(pred.label)
        self.io.publish("identity", ObjectIdentity(label=label, confidence=float(pred.confidence),
                                                  features=[float(v) for v in x], feature_names=list(self.features),
                                                  depth_frame=objs.depth_frame),
                        inputs=provenance(objs.depth_frame, objs, self.weight))
        values = {"confidence": float(pred.confidence), **{n: float(v) for n, v in zip(self.features, x, strict=True)}}
        if pred.label is None:
            self.io.emit(Event.OBJECT_NOT_FOUND, "object unknown", values)
            return Status.FAILURE
        self.io.emit(Event.OBJECT_DETECTED, label, values)
        return Status.SUCCESS
