"""The view translator: link frames by forward kinematics, clouds with their fields, depth back-projected."""

import base64

import msgspec
import numpy as np
import pinocchio as pin
from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory

from contactflow.deploy.foxglove_view import JsonView, ViewTranslator
from contactflow.embodiments import registry
from contactflow.embodiments.messages import DepthImage, RobotInfo, RobotState
from contactflow.fusion.messages import FusedCloud
from contactflow.nodes.wire import NDArray


def _decoded(msg) -> dict:
    """A view message decoded by its own schema (the FileDescriptorSet Foxglove reads), as a dict."""
    schema = type(msg).get_schema()
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(bytes(schema.data)).file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
    return json_format.MessageToDict(cls.FromString(msg.encode()), preserving_proto_field_name=True)


def _floats(cloud: dict, n: int) -> np.ndarray:
    return np.frombuffer(base64.b64decode(cloud["data"]), dtype="<f4").reshape(-1, n)


def _v(d: dict, *keys: str) -> list[float]:
    return [d.get(k, 0.0) for k in keys]  # protobuf leaves zeros out


def test_joint_states_become_the_frames_of_every_link_at_the_robots_base():
    spec = registry.get("melfa")
    model = pin.buildModelFromUrdf(str(spec.urdf()))
    base = np.eye(4)
    base[:3, 3] = [1.0, 2.0, 0.5]
    view = ViewTranslator()
    ((topic, urdf),) = view.add_robot(RobotInfo(robot="m1", embodiment="melfa", base=base.ravel().tolist()))
    assert topic == "/m1/robot_description" and isinstance(urdf, JsonView) and "<robot" in urdf.value["data"]
    q = pin.randomConfiguration(model)
    names = [model.names[j] for j in range(1, model.njoints) if model.joints[j].nq == 1]
    pos = np.array([q[model.joints[model.getJointId(n)].idx_q] for n in names])
    state = RobotState(robot="m1", tick=1, t=2.5, names=names, position=NDArray.of(pos),
                       velocity=NDArray.of(np.zeros_like(pos)), arms=[], hands=[])
    ((topic, msg),) = view.translate("", state)
    assert topic == "/tf"
    tf = _decoded(msg)
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    bodies = {f.name: i for i, f in enumerate(model.frames) if f.type == pin.FrameType.BODY}
    got = {t["child_frame_id"]: t for t in tf["transforms"]}
    assert set(got) == {f"m1/{n}" for n in bodies}
    for name, i in bodies.items():
        T = base @ data.oMf[i].homogeneous
        t = got[f"m1/{name}"]
        assert t["parent_frame_id"] == "world" and t["timestamp"] == "1970-01-01T00:00:02.500Z"
        assert np.allclose(_v(t["translation"], "x", "y", "z"), T[:3, 3], atol=1e-9)
        x, y, z, w = _v(t["rotation"], "x", "y", "z", "w")
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        assert np.allclose(R, T[:3, :3], atol=1e-9)  # the unit quaternion turns the frame as the link is turned
    # at most tf_hz (30) frames per second of the robot's clock; a clock gone back starts over
    later = [msgspec.structs.replace(state, t=t) for t in (2.51, 2.54, 1.0)]
    assert [len(view.translate("", s)) for s in later] == [0, 1, 1]
    assert view.translate("", RobotState(robot="unknown", tick=1, t=0.0, names=[], position=NDArray.of(np.zeros(0)),
                                         velocity=NDArray.of(np.zeros(0)), arms=[], hands=[])) == []


def test_fused_hypotheses_keep_their_likelihood_per_point():
    loc = np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]], np.float32)
    msg = FusedCloud(stamp=1.0, location=NDArray.of(loc), likelihood=NDArray.of(np.array([0.25, 1.0], np.float32)),
                     force=NDArray.of(np.array([0.0, 3.0], np.float32)), direction=NDArray.of(np.zeros((2, 3), np.float32)),
                     sources=NDArray.of(np.array([1, 1], np.uint64)), columns=["r/tactile"])
    ((topic, view),) = ViewTranslator().translate("", msg)
    cloud = _decoded(view)
    assert topic == "/contacts/hypotheses" and [f["name"] for f in cloud["fields"]] == ["x", "y", "z", "likelihood", "force"]
    assert cloud["frame_id"] == "world" and cloud["point_stride"] == 20
    pts = _floats(cloud, 5)
    assert np.allclose(pts[:, :3], loc) and np.allclose(pts[:, 3], [0.25, 1.0]) and np.allclose(pts[:, 4], [0, 3])


def test_a_depth_frame_is_back_projected_into_the_world_without_its_missing_pixels():
    depth = np.full((8, 8), 2.0, np.float32)
    depth[0, 0] = np.nan  # no return
    depth[4, 4] = 0.0  # no return
    K = np.array([[10.0, 0, 4], [0, 10.0, 4], [0, 0, 1]])
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.0, 3.0]
    msg = DepthImage.of(depth, K, T)
    ((topic, view),) = ViewTranslator(depth_stride=1).translate("cf/s/robot/r7/depth", msg)
    assert topic == "/r7/depth"
    pts = _floats(_decoded(view), 4)
    assert len(pts) == 62 and np.allclose(pts[:, 2], 5.0) and np.allclose(pts[:, 3], 2.0)
    # the pixel at (row 4, col 6) lies 2 pixels right of the centre: x = 2 * 2.0 / 10
    assert np.any(np.all(np.isclose(pts[:, :3], [0.4, 0.0, 5.0]), axis=1))


def test_a_generators_cloud_is_shown_on_its_own_topic_with_likelihood_and_type():
    from contactflow.fusion.hypotheses import Hypotheses, HypothesisType
    from contactflow.fusion.messages import HypothesisCloud

    h = Hypotheses.make(np.array([[0.1, 0.0, 0.8], [0.2, 0.0, 0.8]]), np.array([0.3, 0.9]), HypothesisType.NULL)
    ((topic, view),) = ViewTranslator().translate("", HypothesisCloud.of(h, "r", "tactile_left"))
    cloud = _decoded(view)
    assert topic == "/contacts/r/tactile_left" and [f["name"] for f in cloud["fields"]][3:] == ["likelihood", "type"]
    pts = _floats(cloud, 5)
    assert np.allclose(pts[:, :3], h.location) and np.allclose(pts[:, 3], [0.3, 0.9])
    assert np.all(pts[:, 4] == int(HypothesisType.NULL))
