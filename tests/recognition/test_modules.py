"""Every recognition module describes itself and sits in its layer."""

from __future__ import annotations

import pytest

from contactflow.nodes.module import Layer
from contactflow.nodes.status import Event
from contactflow.recognition.primitives.classify_shape import ClassifyShape
from contactflow.recognition.primitives.recognize_object import RecognizeObject
from contactflow.recognition.services.cloud_builder import CloudBuilder
from contactflow.recognition.services.cluster_extractor import ClusterExtractor
from contactflow.recognition.services.grasp_generator import GraspGenerator
from contactflow.recognition.services.plane_detector import PlaneDetector
from contactflow.recognition.services.roi_filter import RoiFilter
from contactflow.recognition.services.self_filter import SelfFilter

SERVICES = (CloudBuilder, PlaneDetector, RoiFilter, SelfFilter, ClusterExtractor, GraspGenerator)
PRIMITIVES = (ClassifyShape, RecognizeObject)


@pytest.mark.parametrize("cls", SERVICES + PRIMITIVES)
def test_module_description(cls):
    d = cls.describe()
    assert d["outputs"] and d["params"]["rate_hz"] > 0 and d["doc"]
    if cls in SERVICES:
        assert cls.layer == Layer.SERVICE and not d["events"]
    else:
        assert cls.layer == Layer.PRIMITIVE
        assert set(d["events"]) == {Event.OBJECT_DETECTED.value, Event.OBJECT_NOT_FOUND.value}


def test_plane_detector_runs_at_one_hertz():
    assert PlaneDetector.Params().rate_hz == 1.0
