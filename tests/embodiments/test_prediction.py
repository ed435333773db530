"""Prediction against sensing: the mismatch detector's decisions on contacts, joints and wrist loads (no simulator)."""

from __future__ import annotations

import numpy as np
import pytest

from contactflow.embodiments.messages import MismatchKind
from contactflow.embodiments.prediction import MismatchDetector, MismatchParams, held_mass

HAND = "right_hand"
AT = np.array([[0.5, -0.2, 0.85]])
NONE = np.zeros((0, 3))


def run(det: MismatchDetector, predicted, sensed, until: float, dt: float = 0.005, fused_dt: float = 0.05,
        pressed=lambda t: False):
    """Feed ``predicted(t)`` and ``pressed(t)`` (the robot's pads) every tick and ``sensed(t)`` every fusion cycle
    up to ``until``; every mismatch."""
    out = []
    for k in range(int(round(until / dt)) + 1):
        t = k * dt
        pts, felt = predicted(t)
        det.predict(t, pts, [HAND] * len(pts), {HAND} if felt and len(pts) else set())
        det.touch(t, {HAND} if pressed(t) else set())
        if k % int(round(fused_dt / dt)) == 0:
            s = sensed(t)
            det.sense(t, s, [HAND] * len(s))
        out += det.check()
    return out


def test_a_contact_predicted_and_sensed_within_the_window_is_no_mismatch():
    # the real contact comes 60 ms after the predicted one, fusion sees it 50 ms later and keeps it 0.3 s after it ends
    det = MismatchDetector()
    found = run(det, lambda t: (AT if 1.0 <= t < 2.0 else NONE, True),
                lambda t: AT + 0.03 if 1.11 <= t < 2.36 else NONE, 3.0, pressed=lambda t: 1.06 <= t < 2.05)
    assert found == []


def test_a_sensed_contact_where_none_was_predicted_is_unexpected_and_reported_once():
    det = MismatchDetector()
    found = run(det, lambda t: (NONE, True), lambda t: AT if t >= 1.0 else NONE, 1.8)
    assert [m.kind for m in found] == [MismatchKind.UNEXPECTED_CONTACT]  # quiet for 1 s after it
    m = found[0]
    assert m.since == pytest.approx(1.0) and m.part == HAND and m.location == pytest.approx(tuple(AT[0]))
    assert m.detail.startswith("a contact sensed at")
    # one that lasts less than sustain (two fused cycles, 50 ms apart) is not: a hand that let go of a can two
    # cycles later than predicted (bench prediction, undisturbed seed 1012, at 20.26 s), a brush
    let_go = lambda end: lambda t: AT if 1.0 <= t < end else NONE  # noqa: E731
    assert run(MismatchDetector(), lambda t: (AT if 1.0 <= t < 1.5 else NONE, True), let_go(1.96), 2.5) == []
    late = run(MismatchDetector(), lambda t: (AT if 1.0 <= t < 1.5 else NONE, True), let_go(2.2), 2.5)
    assert [m.kind for m in late] == [MismatchKind.UNEXPECTED_CONTACT] and late[0].since == pytest.approx(1.9)
    # after the quiet time, a contact that persists is reported again
    det2 = MismatchDetector(MismatchParams(quiet=0.5))
    assert len(run(det2, lambda t: (NONE, True), lambda t: AT if t >= 1.0 else NONE, 1.8)) == 2


def test_a_predicted_contact_that_presses_the_pads_and_does_not_on_the_robot_is_missing_a_light_or_brief_one_is_not():
    det = MismatchDetector()
    # the can leaves the hand at 1.5 s; fusion holds the contact 0.3 s more
    found = run(det, lambda t: (AT if t >= 1.0 else NONE, True), lambda t: AT if 1.0 <= t < 1.8 else NONE, 2.5,
                pressed=lambda t: 1.0 <= t < 1.5)
    assert [m.kind for m in found] == [MismatchKind.MISSING_CONTACT]
    # absent 0.15 s, and the fusion's hold 0.3 s, after the last fused cycle
    assert found[0].since == pytest.approx(1.8 + 0.15 + 0.3, abs=0.055)
    assert found[0].part == HAND and found[0].location == pytest.approx(tuple(AT[0]))
    # pads pressed as predicted: nothing missing
    assert run(MismatchDetector(), lambda t: (AT if t >= 1.0 else NONE, True), lambda t: AT if t >= 1.0 else NONE,
               2.0, pressed=lambda t: t >= 1.03) == []
    # a contact the prediction's pads do not feel (the palm, a phalanx) is not expected on the pads
    assert run(MismatchDetector(), lambda t: (AT if t >= 1.0 else NONE, False), lambda t: NONE, 2.0) == []
    # a brush in passing (50 ms)
    assert run(MismatchDetector(), lambda t: (AT if 1.0 <= t < 1.05 else NONE, True), lambda t: NONE, 2.0) == []
    # a grasp held by the phalanges (pads silent) whose fused contact drops out for 0.25 s (< the fusion's hold: for
    # the robot it was never broken) is no mismatch (bench prediction, undisturbed seed 1003: missing_contact at
    # 12.17 s while the can stayed held); for 0.8 s it is, once absent and hold passed since the last fused cycle
    held = lambda gap: lambda t: AT if t >= 1.0 and not 1.5 <= t < 1.5 + gap else NONE  # noqa: E731
    assert run(MismatchDetector(), lambda t: (AT if t >= 1.0 else NONE, True), held(0.25), 2.5) == []
    found = run(MismatchDetector(), lambda t: (AT if t >= 1.0 else NONE, True), held(0.8), 2.5)
    assert [m.kind for m in found] == [MismatchKind.MISSING_CONTACT] and found[0].since == pytest.approx(1.45 + 0.15 + 0.3, abs=0.055)
    # the pads released for 0.1 s (< absent) is no mismatch either
    assert run(MismatchDetector(), lambda t: (AT if t >= 1.0 else NONE, True), lambda t: AT if t >= 1.0 else NONE,
               2.5, pressed=lambda t: t >= 1.0 and not 1.5 <= t < 1.6) == []


def test_a_wrist_load_off_by_an_impact_a_few_ticks_early_is_no_mismatch_a_steady_offset_is_one():
    det = MismatchDetector()
    spike = lambda t, at: np.array([0.0, 0.0, 30.0 if at <= t < at + 0.05 else 0.0])  # noqa: E731
    for k in range(400):
        t = k * 0.005
        det.force(t, "right", spike(t, 1.0), spike(t, 1.04))  # the real impact 40 ms later (< window)
    assert det.check() == []
    det = MismatchDetector()
    found = []
    for k in range(380):
        t = k * 0.005
        det.force(t, "right", np.zeros(3), np.array([0.0, 0.0, -6.0 if t >= 1.0 else 0.0]))  # 0.6 kg more
        found += det.check()
    assert [m.kind for m in found] == [MismatchKind.FORCE]  # reported again at 2.1 s
    assert found[0].since == pytest.approx(1.0) and found[0].value == pytest.approx(6.0) and found[0].part == "right"
    assert found[0].delta == pytest.approx((0.0, 0.0, -6.0))  # measured minus predicted: what the model can learn


def test_a_held_object_weighs_what_a_vertical_load_difference_says_a_push_or_a_pull_beyond_payload_teaches_nothing():
    assert held_mass(0.2, np.array([0.0, 0.0, -5.886]), payload=2.0) == pytest.approx(0.8)  # 0.6 kg heavier
    assert held_mass(0.8, np.array([0.3, -0.2, 5.886]), payload=2.0) == pytest.approx(0.2)  # lighter, a little tilt
    assert held_mass(0.2, np.array([6.0, 0.0, -1.0]), payload=2.0) is None  # sideways: a snag, not a weight
    assert held_mass(0.2, np.array([0.0, 0.0, -40.0]), payload=2.0) is None  # 4.3 kg: a pull, beyond the payload
    assert held_mass(0.2, np.array([0.0, 0.0, 3.0]), payload=2.0) is None  # it would weigh nothing: held up
    assert held_mass(0.2, np.zeros(3), payload=2.0) is None


def test_joints_off_beyond_the_bound_for_the_sustain_time_is_a_mismatch():
    det = MismatchDetector()
    assert det.joints(1.0, 0.3, "j2") is None  # not sustained yet
    assert det.joints(1.05, 0.05, "j2") is None  # back under the bound: the episode does not end at once
    assert det.joints(1.1, 0.3, "j2") is not None  # still the episode of 1.0, sustained 0.1 s
    assert det.joints(1.2, 0.3, "j2") is None  # quiet for 1 s
    again = det.joints(2.1, 0.3, "j2")  # the same episode, reported again after the quiet time
    assert again is not None and again.since == pytest.approx(1.0)
    for k in range(30):
        det.joints(2.2 + 0.005 * k, 0.0, "j2")  # 0.15 s under: the episode ends
    assert det.joints(3.5, 0.3, "j2") is None and det.joints(3.6, 0.3, "j2").since == pytest.approx(3.5)


@pytest.mark.parametrize("field, value", [("window", 0.0), ("radius", -1.0), ("quiet", -1.0), ("horizon", 0.2)])
def test_bad_detector_params_name_the_field(field, value):
    with pytest.raises(ValueError, match=rf"params\.{field}"):
        MismatchDetector(MismatchParams(**{field: value}))


def test_an_object_seen_farther_than_the_bound_from_its_prediction_is_a_mismatch():
    det = MismatchDetector()
    assert det.object(0.5, "cyl", np.array([0.55, -0.3, 0.87]), 0.012) is None  # within 2.5 cm: the reality gap
    m = det.object(3.0, "cyl", np.array([0.60, -0.3, 0.87]), 0.05)
    assert m is not None and m.kind is MismatchKind.OBJECT and m.part == "cyl" and m.value == 0.05
    assert "5.0 cm" in m.detail and m.location == pytest.approx((0.60, -0.3, 0.87))


def test_the_window_median_is_numpys_median():
    from contactflow.embodiments.prediction import _median

    rng = np.random.default_rng(3)
    for k in range(1, 42):
        x = rng.normal(size=(k, 6)) * 10
        assert np.array_equal(_median(x), np.median(x, axis=0)), k
