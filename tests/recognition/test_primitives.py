"""Perceptual primitives: events, outcomes and 'unknown' instead of forced answers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from contactflow.nodes.status import Event, Status
from contactflow.nodes.testing import FakeIO, run_module
from contactflow.nodes.wire import stamp
from contactflow.recognition.classifiers import NormalDensityClassifier, knowledge
from contactflow.recognition.features import FEATURES, object_features
from contactflow.recognition.messages import MeasuredWeight, SegmentedObjects, depth_image
from contactflow.recognition.pipeline import SegmentationPipeline
from contactflow.recognition.primitives.classify_shape import ClassifyShape
from contactflow.recognition.primitives.recognize_object import RecognizeObject
from contactflow.recognition.testing import Placed, TableScene, three_objects


@pytest.fixture(scope="module")
def segmented():
    s = three_objects()
    depth = s.render(noise=0.001, seed=4)
    frame = stamp(depth_image(depth, s.K, s.pose), "site/cam/camera/depth", 9, 0.0)
    res = SegmentationPipeline().process_depth(depth, s.K, s.pose)
    objs = stamp(SegmentedObjects.of(res.clusters, frame.hdr.id), "site/vision/clusters/objects", 3, 0.0)
    return s, frame, objs


def _nearest_index(objs, xy):
    return int(np.argmin([np.linalg.norm(np.asarray(o.centroid[:2]) - xy) for o in objs.objects]))


@pytest.mark.parametrize(("xy", "expected"), [((0.55, 0.25), "cylinder"), ((0.65, -0.15), "box")])
def test_classify_shape_of_segmented_objects(segmented, xy, expected):
    _, frame, objs = segmented
    mod = ClassifyShape("shape", ClassifyShape.Params(index=_nearest_index(objs, np.array(xy))))
    io = FakeIO()
    io.module = mod
    mod.setup(io)
    mod.start()
    io.feed("depth", frame)
    io.feed("objects", objs)
    assert mod.step() == Status.SUCCESS
    ev = io.events[-1]
    assert ev.event == Event.OBJECT_DETECTED and ev.detail == expected
    shape = io.published["shape"][-1]
    assert shape.label == expected and np.isclose(sum(shape.probabilities), 1.0)
    assert shape.hdr.inputs[0] == frame.hdr.id


def test_classify_shape_without_the_depth_frame_fails_after_timeout(segmented):
    _, _, objs = segmented
    io = FakeIO()
    io.feed("objects", objs)
    status = run_module(ClassifyShape("shape", ClassifyShape.Params(timeout=0.3)), io, steps=10)
    assert status == Status.FAILURE and io.event_labels() == [Event.OBJECT_NOT_FOUND]


BOXES = {"small": (0.10, 0.06, 0.04), "mid": (0.16, 0.10, 0.06), "big": (0.24, 0.12, 0.08)}
WEIGHT = {k: 450 * 9.81 * float(np.prod(v)) for k, v in BOXES.items()}


def _knowledge(tmp_path):
    rng = np.random.default_rng(0)
    X, y = [], []
    for name, size in BOXES.items():
        for _ in range(40):
            X.append(object_features(np.asarray(size) + rng.normal(0, 0.003, 3), WEIGHT[name] + rng.normal(0, 0.05)))
            y.append(name)
    path = tmp_path / "kb.json"
    path.write_text(json.dumps(knowledge(NormalDensityClassifier().fit(np.array(X), y), FEATURES)))
    return path


def _objects_of(size):
    s = TableScene([Placed("box", size, (0.55, 0.0), 0.4)])
    res = SegmentationPipeline().process_depth(s.render(noise=0.001, seed=2), s.K, s.pose)
    return SegmentedObjects.of(res.clusters)


def _recognize(tmp_path, size, weight):
    mod = RecognizeObject("recognize", RecognizeObject.Params(knowledge=str(_knowledge(tmp_path))))
    io = FakeIO()
    io.module = mod
    mod.setup(io)
    mod.start()
    io.feed("objects", _objects_of(size))
    io.feed("weight", MeasuredWeight(weight=weight))
    return mod, io, mod.step()


def test_recognize_object_from_vision_and_weight(tmp_path):
    mod, io, status = _recognize(tmp_path, BOXES["mid"], WEIGHT["mid"])
    assert status == Status.SUCCESS
    assert io.events[-1].event == Event.OBJECT_DETECTED and io.events[-1].detail == "mid"
    ident = io.published["identity"][-1]
    assert ident.label == "mid" and ident.confidence > 0.9 and ident.feature_names == list(FEATURES)
    assert mod.recognizer.learned == 1


def test_recognize_object_says_unknown_for_a_new_object(tmp_path):
    _, io, status = _recognize(tmp_path, BOXES["mid"], 3 * WEIGHT["mid"])
    assert status == Status.FAILURE
    assert io.events[-1].event == Event.OBJECT_NOT_FOUND
    assert io.published["identity"][-1].label == "unknown"


def test_recognize_object_waits_for_the_weight_then_fails(tmp_path):
    mod = RecognizeObject("recognize", RecognizeObject.Params(knowledge=str(_knowledge(tmp_path)), timeout=0.3))
    io = FakeIO()
    io.feed("objects", _objects_of(BOXES["mid"]))
    assert run_module(mod, io, steps=10) == Status.FAILURE
    assert "weight" in io.events[-1].detail


def test_recognize_object_names_a_bad_knowledge_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    mod = RecognizeObject("recognize", RecognizeObject.Params(knowledge=str(bad)))
    with pytest.raises(ValueError, match="bad.json"):
        mod.setup(FakeIO())
