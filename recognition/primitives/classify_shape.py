"""Classify shape primitive (V4, thesis §8.4.2): box, cylinder or sphere from the silhouette, or unknown."""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

from contactflow.embodiments.messages import DepthImage
from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.recognition.messages import SegmentedObjects, ShapeClass, depth_arrays, provenance
from contactflow.recognition.shape import (
    UNKNOWN,
    ShapeClassifier,
    curvedness,
    object_mask,
    silhouette_contour,
)


class ClassifyShape(Module):
    """Classifies one segmented object by the curvedness of its silhouette in the depth
    frame it was cut from. OBJECT_DETECTED (detail = class, values = percentages) on a
    confident answer; OBJECT_NOT_FOUND when the class is unknown (look from elsewhere) or
    no object arrives within ``timeout``."""

    layer = Layer.PRIMITIVE
    inputs = (Port("depth", DepthImage, "depth frames of the camera"),
              Port("objects", SegmentedObjects, "segmented objects"))
    outputs = (Port("shape", ShapeClass, "class, percentages and curvedness"),)
    events = (Event.OBJECT_DETECTED, Event.OBJECT_NOT_FOUND)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 10.0  # Hz
        timeout: float = 3.0  # s
        index: int = 0  # which object (largest first)
        confidence: float = 0.70  # the 70 % rule (§8.5.2)
        # µK, σK of box, cylinder, sphere: 19 views of training shapes 1-9 at 40° elevation
        # (contactflow bench recognition, Table 8.1)
        mu: tuple[float, ...] = (0.0094, 0.534, 1.0)
        sigma: tuple[float, ...] = (0.049, 0.158, 0.01)
        frames: int = 30  # depth frames kept to find the one an object was cut from

    def setup(self, io) -> None:
        super().setup(io)
        self.frames: OrderedDict = OrderedDict()
        self.on_params(None)

    def on_params(self, old) -> None:
        p = self.params
        self.classifier = ShapeClassifier.from_stats(p.mu, p.sigma, p.confidence)

    def start(self) -> None:
        self.t0 = self.io.now
        self.io.take("objects")

    def step(self) -> Status:
        for f in self.io.take("depth"):
            self.frames[f.hdr.id] = f
            while len(self.frames) > max(self.params.frames, 1):
                self.frames.popitem(last=False)
        msgs = self.io.take("objects")
        if msgs and len(msgs[-1].objects) > self.params.index:
            objs = msgs[-1]
            frame = self.frames.get(objs.depth_frame)
            if frame is None and not objs.depth_frame.source and self.frames:
                frame = next(reversed(self.frames.values()))
            if frame is not None:
                return self._classify(objs, frame)
        if self.io.now - self.t0 >= self.params.timeout:
            self.io.emit(Event.OBJECT_NOT_FOUND, f"no object {self.params.index} with its depth frame")
            return Status.FAILURE
        return Status.RUNNING

    def _classify(self, objs: SegmentedObjects, frame: DepthImage) -> Status:
        depth, K, T = depth_arrays(frame)
        box = objs.objects[self.params.index].box.box()
        c = curvedness(silhouette_contour(object_mask(depth, K, T, box)))
        label, p = self.classifier.classify(c)
        probs = [float(v) for v in p]
        self.io.publish("shape", ShapeClass(label=label, classes=list(self.classifier.classes), probabilities=probs,
                                            curvedness=float(c), depth_frame=objs.depth_frame),
                        inputs=provenance(objs.depth_frame, objs, frame))
        values = {f"p_{k}": v for k, v in zip(self.classifier.classes, probs, strict=True)}
        values["curvedness"] = float(c)
        if label == UNKNOWN:
            self.io.emit(Event.OBJECT_NOT_FOUND, "shape unknown", values)
            return Status.FAILURE
        self.io.emit(Event.OBJECT_DETECTED, label, values)
        return Status.SUCCESS
