"""Wire format: round trips, plain-msgpack readability, and validation of hostile payloads."""

import contextlib
import math

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from contactflow.embodiments.messages import DepthImage, RobotState, WrenchSample
from contactflow.nodes.messages import Array, ControlRequest, EventMsg, Vector
from contactflow.nodes.status import Event
from contactflow.nodes.wire import (
    SCHEMA_VERSION,
    NDArray,
    WireError,
    decode,
    decode_any,
    encode,
    stamp,
)


def test_event_is_a_plain_msgpack_map_with_named_fields():
    msg = stamp(EventMsg(event=Event.GRASP_LOST, module="r/n/grasp", detail="slip"), "r/n/grasp", 7, 1.5)
    raw = msgpack.unpackb(encode(msg))
    assert raw["type"] == "event"
    assert raw["event"] == "grasp_lost"
    assert raw["hdr"]["seq"] == 7 and raw["hdr"]["schema"] == SCHEMA_VERSION
    assert decode(encode(msg), EventMsg) == msg


def test_ndarray_round_trip_keeps_dtype_and_shape():
    a = np.arange(24, dtype=np.float32).reshape(2, 3, 4)
    msg = decode(encode(Array(array=NDArray.of(a))), Array)
    np.testing.assert_array_equal(msg.array.numpy(), a)
    raw = msgpack.unpackb(encode(Array(array=NDArray.of(a))))
    assert raw["array"]["dtype"] == "float32" and raw["array"]["shape"] == [2, 3, 4]


def test_empty_arrays_round_trip():
    for shape in ((0,), (0, 3), (2, 0, 4)):
        a = np.zeros(shape, dtype=np.float32)
        back = decode(encode(Array(array=NDArray.of(a))), Array).array.numpy()
        assert back.shape == shape and back.dtype == np.float32


def test_ndarray_with_inconsistent_size_is_refused():
    raw = msgpack.packb({"type": "array", "array": {"dtype": "float64", "shape": [10], "data": b"\0" * 8}})
    with pytest.raises(WireError, match="needs 80"):
        decode(raw, Array, "cf/x/out")


def test_unknown_schema_version_names_key_and_field():
    raw = msgpack.packb({"type": "vector", "values": [1.0], "hdr": {"schema": 99}})
    with pytest.raises(WireError) as err:
        decode(raw, Vector, "cf/site/m/r/n/mod/out/x")
    assert "cf/site/m/r/n/mod/out/x" in str(err.value) and "schema version 99" in str(err.value)


def test_wrong_field_type_names_the_field():
    raw = msgpack.packb({"type": "vector", "values": ["a"]})
    with pytest.raises(WireError, match=r"values\[0\]"):
        decode(raw, Vector, "k")


def test_oversized_payload_is_refused_before_decoding():
    with pytest.raises(WireError, match="exceeds"):
        decode(b"\x00" * (10 << 20), Vector, "k")


def test_decode_any_dispatches_on_type_tag():
    msg = ControlRequest(cmd="run")
    assert isinstance(decode_any(encode(msg)), ControlRequest)
    with pytest.raises(WireError, match="unknown message type"):
        decode_any(msgpack.packb({"type": "nope"}))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=512))
def test_random_bytes_raise_only_wire_errors(data):
    for cls in (EventMsg, Vector, ControlRequest, Array):
        with contextlib.suppress(WireError):
            decode(data, cls, "fuzz")


json_like = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=8) | st.binary(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=4),
    max_leaves=20,
)


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(st.sampled_from(["type", "event", "module", "values", "hdr", "cmd", "array"]), json_like))
def test_structured_garbage_raises_only_wire_errors(fields):
    data = msgpack.packb(fields, use_bin_type=True)
    for cls in (EventMsg, Vector, ControlRequest, Array):
        with contextlib.suppress(WireError):
            decode(data, cls, "fuzz")


_ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=300, deadline=None)
@given(values=st.lists(_ANY_FLOAT, max_size=8), extra=st.dictionaries(st.text(max_size=3), _ANY_FLOAT, max_size=3),
       array=st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), max_size=12))
def test_a_message_is_refused_exactly_when_it_carries_a_non_finite_number(values, extra, array):
    vec = encode(Vector(values=values))
    ev = encode(EventMsg(event=Event.SUCCESS, module="m", values=extra))
    arr = encode(Array(array=NDArray.of(np.asarray(array, dtype=np.float32))))
    state = encode(RobotState(robot="r", tick=1, t=0.0, names=[], position=NDArray.of(np.zeros(0)),
                              velocity=NDArray.of(np.zeros(0)), arms=[], hands=[],
                              wrenches=[WrenchSample(arm="a", force=values[:3], torque=[], frame="f", rotation=[],
                                                      external_force=[], external_torque=[])]))
    cases = [(vec, Vector, values), (ev, EventMsg, list(extra.values())), (arr, Array, array),
             (state, RobotState, values[:3])]
    for payload, type_, numbers in cases:
        finite = all(math.isfinite(v) for v in numbers)
        if finite:
            decode(payload, type_, "k")
        else:
            with pytest.raises(WireError, match="is not a finite number"):
                decode(payload, type_, "cf/s/k")


def test_a_non_finite_number_in_a_list_of_floats_is_named_by_its_index():
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(WireError, match=r"Vector\.values\[2\] is not a finite number"):
            decode(encode(Vector(values=[0.0, 1.5, bad, math.nan])), Vector, "k")
    assert decode(encode(Vector(values=[0.0, -1e308, 5e-324])), Vector, "k").values == [0.0, -1e308, 5e-324]


def test_a_non_finite_header_stamp_is_refused():
    msg = stamp(Vector(values=[1.0]), "a/b/c", 1, float("inf"))
    with pytest.raises(WireError, match=r"Vector.hdr.t_sim is not a finite number"):
        decode(encode(msg), Vector, "k")


def test_a_depth_image_may_carry_rep117_non_finite_pixels_but_not_a_non_finite_pose():
    depth = np.ones((4, 5), np.float32)
    depth[0, 0], depth[1, 1], depth[2, 2] = np.nan, -np.inf, np.inf  # no return, too near, too far
    msg = decode(encode(DepthImage.of(depth, np.eye(3), np.eye(4))), DepthImage, "k")
    assert np.isnan(msg.depth.numpy()[0, 0])
    pose = np.eye(4)
    pose[0, 3] = np.nan
    with pytest.raises(WireError, match=r"DepthImage.T_world_cam\[3\] is not a finite number"):
        decode(encode(DepthImage.of(depth, np.eye(3), pose)), DepthImage, "k")
