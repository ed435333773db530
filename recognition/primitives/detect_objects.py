"""Detect objects primitive: waits for segmented objects in the region of interest."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from contactflow.nodes.module import Layer, Module, Port
from contactflow.nodes.status import Event, Status
from contactflow.recognition.messages import SegmentedObjects


class DetectObjects(Module):
    """Succeeds with OBJECT_DETECTED once at least ``min_objects`` objects are segmented
    (within ``max_distance`` of ``origin``); fails with OBJECT_NOT_FOUND after ``timeout``."""

    layer = Layer.PRIMITIVE
    inputs = (Port("objects", SegmentedObjects, "segmented objects from the cluster extractor"),)
    outputs = (Port("target", SegmentedObjects, "the detected objects, nearest to origin first"),)
    events = (Event.OBJECT_DETECTED, Event.OBJECT_NOT_FOUND)

    @dataclass(frozen=True)
    class Params:
        rate_hz: float = 10.0  # Hz
        timeout: float = 3.0  # s without objects before OBJECT_NOT_FOUND
        min_objects: int = 1
        origin: tuple[float, ...] = (0.0, 0.0, 0.0)  # m, world point objects are sorted by
        max_distance: float = 10.0  # m from origin

    def start(self) -> None:
        self.t0 = self.io.now
        self.io.take("objects")

    def step(self) -> Status:
        p = self.params
        msgs = self.io.take("objects")
        if msgs:
            msg = msgs[-1]
            origin = np.asarray(p.origin, float)
            dist = [float(np.linalg.norm(np.asarray(o.centroid) - origin)) for o in msg.objects]
            keep = sorted((d, i) for i, d in enumerate(dist) if d <= p.max_distance)
            if len(keep) >= max(p.min_objects, 1):
                objs = [msg.objects[i] for _, i in keep]
                self.io.publish("target", SegmentedObjects(objects=objs, depth_frame=msg.depth_frame))
                c, ext = objs[0].centroid, sorted(objs[0].box.extent, reverse=True)
                self.io.emit(Event.OBJECT_DETECTED, f"{len(objs)} object(s)",
                             {"count": float(len(objs)), "x": c[0], "y": c[1], "z": c[2],
                              "d1": ext[0], "d2": ext[1], "d3": ext[2]})
                return Status.SUCCESS
        if self.io.now - self.t0 >= p.timeout:
            self.io.emit(Event.OBJECT_NOT_FOUND, f"no object within {p.timeout} s")
            return Status.FAILURE
        return Status.RUNNING
