"""Key-space messages in Foxglove's schemas: the channels of the live view and of a recording's view.

A pure translator: it takes typed wire messages and returns ``(topic, foxglove message)``
pairs; the live view module logs them to a Foxglove WebSocket server, the recorder writes
them into the MCAP file beside the key-space channels, so both show the same panels.

Topics (every frame is in ``world``; a robot's links are ``<robot>/<link>``):
    /tf                         FrameTransforms  every robot's links, from joint states by pinocchio (<= tf_hz per robot)
    /contacts/hypotheses        PointCloud       fused hypotheses H(x), field ``likelihood`` to colour by
    /contacts/<robot>/<gen>     PointCloud       one generator's hypotheses (likelihood, type)
    /contacts/fused             SceneUpdate      condensed contacts: spheres sized by sigma
    /contacts/events            Log              contact made / broken
    /<robot>/depth              PointCloud       a depth frame back-projected (every ``stride``-th pixel)
    /vision/objects             SceneUpdate      segmented objects' boxes
    /task/progress              Log              a dispatched task's abstract state
    /<robot>/robot_description  JSON {data}      the robot's URDF (frame prefix ``<robot>/``), once
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import foxglove.messages as fm
import numpy as np
import pinocchio as pin

from contactflow.abstraction.messages import AbstractProgressMsg
from contactflow.embodiments.messages import DepthImage, RobotInfo, RobotState
from contactflow.fusion.messages import ContactEventMsg, ContactList, FusedCloud, HypothesisCloud
from contactflow.nodes.wire import Message
from contactflow.recognition.messages import SegmentedObjects

WORLD = "world"
TOPICS = ("/tf", "/contacts/hypotheses", "/contacts/fused", "/contacts/events", "/vision/objects", "/task/progress")
"""The view's fixed topics (each robot adds ``/<robot>/depth``)."""


def _stamp(t: float) -> fm.Timestamp:
    sec = math.floor(t)
    return fm.Timestamp(sec=int(sec), nsec=int((t - sec) * 1e9))


def _quat(R: np.ndarray) -> fm.Quaternion:
    q = pin.Quaternion(np.asarray(R, dtype=float))
    return fm.Quaternion(x=q.x, y=q.y, z=q.z, w=q.w)


def _points(xyz: np.ndarray, extra: dict[str, np.ndarray], t: float) -> fm.PointCloud:
    cols = [np.asarray(xyz, np.float32).reshape(-1, 3)] + [np.asarray(v, np.float32).reshape(-1, 1) for v in extra.values()]
    data = np.ascontiguousarray(np.hstack(cols), dtype="<f4")
    names = ["x", "y", "z", *extra]
    fields = [fm.PackedElementField(name=n, offset=4 * i, type=fm.PackedElementFieldNumericType.Float32)
              for i, n in enumerate(names)]
    return fm.PointCloud(timestamp=_stamp(t), frame_id=WORLD, pose=fm.Pose(position=fm.Vector3(x=0, y=0, z=0),
                         orientation=fm.Quaternion(x=0, y=0, z=0, w=1)), point_stride=4 * len(names),
                         fields=fields, data=data.tobytes())


@dataclass(frozen=True)
class JsonView:
    """A view message without a Foxglove schema: JSON with its JSON schema."""

    schema_name: str
    schema: dict
    value: dict


URDF_SCHEMA = {"type": "object", "properties": {"data": {"type": "string", "description": "URDF XML"}}}


@dataclass
class _Robot:
    """A robot's kinematic model, for its links' frames."""

    name: str
    model: object  # pinocchio.Model
    data: object  # pinocchio.Data
    base: np.ndarray  # (4, 4) world pose of the base
    urdf: str  # the composed URDF


class ViewTranslator:
    """Typed key-space messages -> ``(topic, foxglove message)`` pairs (pure; no I/O but reading URDFs)."""

    def __init__(self, depth_stride: int = 4, tf_hz: float = 30.0) -> None:
        self.depth_stride = depth_stride
        self.tf_period = 1.0 / tf_hz  # s of the robot's clock: a viewer needs no 200 Hz link frames
        self.robots: dict[str, _Robot] = {}
        self._last_tf: dict[str, float] = {}

    def add_robot(self, info: RobotInfo) -> list[tuple[str, object]]:
        """Learn a robot from its world's info answer; returns the message carrying its URDF."""
        from contactflow.embodiments import registry

        path = registry.get(info.embodiment).urdf()
        model = pin.buildModelFromUrdf(str(path))
        urdf = path.read_text()
        self.robots[info.robot] = _Robot(info.robot, model, model.createData(),
                                         np.asarray(info.base, float).reshape(4, 4), urdf)
        return [(f"/{info.robot}/robot_description", JsonView("std_msgs/String", URDF_SCHEMA, {"data": urdf}))]

    def translate(self, key: str, msg: Message) -> list[tuple[str, object]]:
        """The view messages ``msg`` (received on ``key``, "" when unknown) becomes; [] for one the view does not show."""
        if isinstance(msg, RobotState):
            return self._tf(msg)
        if isinstance(msg, FusedCloud):
            xyz = msg.location.numpy()
            return [("/contacts/hypotheses", _points(xyz, {"likelihood": msg.likelihood.numpy(),
                                                            "force": msg.force.numpy()}, msg.stamp))]
        if isinstance(msg, HypothesisCloud):
            return [(f"/contacts/{msg.robot}/{msg.generator}",
                     _points(msg.location.numpy(), {"likelihood": msg.likelihood.numpy(), "type": msg.kind.numpy()},
                             msg.stamp))]
        if isinstance(msg, ContactList):
            return [("/contacts/fused", self._contacts(msg))]
        if isinstance(msg, ContactEventMsg):
            x, y, z = msg.location
            return [("/contacts/events", fm.Log(timestamp=_stamp(msg.t), level=fm.LogLevel.Info, name=msg.robot,
                     message=f"{msg.event.value} #{msg.contact_id} {msg.link or msg.robot} "
                             f"at ({x:.3f}, {y:.3f}, {z:.3f}) p={msg.likelihood:.2f}", file=key, line=0))]
        if isinstance(msg, DepthImage):
            return self._depth(key, msg)
        if isinstance(msg, SegmentedObjects):
            return [("/vision/objects", self._objects(msg))]
        if isinstance(msg, AbstractProgressMsg):
            text = " ".join(p for p in (msg.kind, msg.state, msg.transition, msg.event, msg.concrete) if p)
            return [("/task/progress", fm.Log(timestamp=_stamp(msg.hdr.t_wall), level=fm.LogLevel.Info,
                                              name=f"{msg.task_id}/{msg.robot}", message=text, file=key, line=0))]
        return []

    def _tf(self, msg: RobotState) -> list[tuple[str, object]]:
        r = self.robots.get(msg.robot)
        last = self._last_tf.get(msg.robot)
        if r is None or (last is not None and last <= msg.t < last + self.tf_period):
            return []  # a clock gone back (a new run, a replay) starts over
        self._last_tf[msg.robot] = msg.t
        model, data = r.model, r.data
        q = pin.neutral(model)
        pos = msg.position.numpy()
        for name, v in zip(msg.names, pos, strict=False):
            if model.existJointName(name):
                j = model.joints[model.getJointId(name)]
                if j.nq == 1:
                    q[j.idx_q] = v
        pin.framesForwardKinematics(model, data, q)
        stamp = _stamp(msg.t)
        out = []
        for i, f in enumerate(model.frames):
            if f.type != pin.FrameType.BODY:
                continue
            T = r.base @ data.oMf[i].homogeneous
            out.append(fm.FrameTransform(timestamp=stamp, parent_frame_id=WORLD, child_frame_id=f"{r.name}/{f.name}",
                                         translation=fm.Vector3(x=T[0, 3], y=T[1, 3], z=T[2, 3]), rotation=_quat(T[:3, :3])))
        return [("/tf", fm.FrameTransforms(transforms=out))]

    def _contacts(self, msg: ContactList) -> fm.SceneUpdate:
        spheres = []
        for c in msg.contacts:
            d = max(2 * c.sigma, 0.01)
            spheres.append(fm.SpherePrimitive(
                pose=fm.Pose(position=fm.Vector3(x=c.location[0], y=c.location[1], z=c.location[2]),
                             orientation=fm.Quaternion(x=0, y=0, z=0, w=1)),
                size=fm.Vector3(x=d, y=d, z=d), color=fm.Color(r=1.0, g=0.2, b=0.1, a=0.3 + 0.7 * c.likelihood)))
        entity = fm.SceneEntity(timestamp=_stamp(msg.stamp), frame_id=WORLD, id="contacts", spheres=spheres)
        return fm.SceneUpdate(entities=[entity])

    def _depth(self, key: str, msg: DepthImage) -> list[tuple[str, object]]:
        parts = key.split("/")
        # on a robot's depth key (cf/<site>/robot/<robot>/depth) the key names it, else the producer's address does
        robot = parts[3] if len(parts) == 5 and parts[2] == "robot" else msg.hdr.source.split("/")[0] or "camera"
        s = self.depth_stride
        depth = msg.depth.numpy()[::s, ::s]
        K = np.asarray(msg.K, float).reshape(3, 3)
        rows, cols = np.nonzero(np.isfinite(depth) & (depth > 0))
        z = depth[rows, cols].astype(float)
        x = (cols * s - K[0, 2]) * z / K[0, 0]
        y = (rows * s - K[1, 2]) * z / K[1, 1]
        T = np.asarray(msg.T_world_cam, float).reshape(4, 4)
        xyz = np.stack([x, y, z], axis=1) @ T[:3, :3].T + T[:3, 3]
        return [(f"/{robot}/depth", _points(xyz, {"depth": z}, msg.hdr.t_sim))]

    def _objects(self, msg: SegmentedObjects) -> fm.SceneUpdate:
        cubes = []
        for o in msg.objects:
            b = o.box.box()
            size = np.maximum(b.extent, 1e-3)
            cubes.append(fm.CubePrimitive(
                pose=fm.Pose(position=fm.Vector3(x=b.center[0], y=b.center[1], z=b.center[2]), orientation=_quat(b.rotation)),
                size=fm.Vector3(x=size[0], y=size[1], z=size[2]), color=fm.Color(r=0.2, g=0.6, b=1.0, a=0.4)))
        entity = fm.SceneEntity(timestamp=_stamp(msg.depth_t or msg.hdr.t_sim), frame_id=WORLD, id="objects", cubes=cubes)
        return fm.SceneUpdate(entities=[entity])
