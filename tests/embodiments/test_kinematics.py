"""pinocchio and SAPIEN agree on every link pose; the kinematics wrapper's task frames and Jacobians."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from contactflow.embodiments.control.kinematics import Kinematics, KinematicsError
from contactflow.embodiments.world import World


@pytest.mark.parametrize("name", ["tombatossals", "melfa", "baxter"])
def test_pinocchio_and_sapien_link_poses_agree(name):
    w = World()
    art = w.add_robot(name)
    kin = Kinematics(art.spec.urdf(), art.base)
    rng = np.random.default_rng(1)
    for _ in range(3):
        q = np.clip(art.home_q() + rng.uniform(-0.4, 0.4, len(art.joint_names)), art.lower, art.upper)
        art.set_state(q)
        kin.update(dict(zip(art.joint_names, q, strict=True)))
        errors = [np.linalg.norm(kin.frame_pose(n)[:3, 3] - art.link_pose(n)[:3, 3]) for n in art.links]
        rot = [np.linalg.norm(kin.frame_pose(n)[:3, :3] - art.link_pose(n)[:3, :3]) for n in art.links]
        assert max(errors) < 1e-3
        assert max(rot) < 1e-3


def test_jacobian_matches_finite_differences_and_task_frames(tmp_path):
    from contactflow.embodiments import registry

    spec = registry.get("melfa")
    kin = Kinematics(spec.urdf(tmp_path))
    q = np.array([0.1, -1.2, 1.5, -1.0, -1.4, 0.3, 0.02, 0.02])
    kin.update(q)
    J = kin.jacobian("panda_hand_tcp")
    p0 = kin.frame_pose("panda_hand_tcp")[:3, 3]
    eps = 1e-6
    for i in range(6):
        dq = q.copy()
        dq[i] += eps
        kin.update(dq)
        assert np.allclose((kin.frame_pose("panda_hand_tcp")[:3, 3] - p0) / eps, J[:3, i], atol=1e-4)
    kin.update(q)
    off = np.eye(4)
    off[2, 3] = 0.1
    kin.add_task_frame("tool_tip", "panda_hand_tcp", off)
    assert np.allclose(kin.frame_pose("tool_tip"), kin.frame_pose("panda_hand_tcp") @ off)
    assert np.allclose(kin.frame_pose("tool_tip", relative_to="panda_hand_tcp"), off)
    assert "tool_tip" in kin.frames and "wrist_3_link" in kin.frames
    with pytest.raises(KinematicsError, match="unknown frame 'nope'"):
        kin.frame_pose("nope")


def test_wrapper_matches_raw_pinocchio(tmp_path):
    from contactflow.embodiments import registry

    urdf = str(registry.get("baxter").urdf(tmp_path))
    kin = Kinematics(urdf)
    model = pin.buildModelFromUrdf(urdf)
    data = model.createData()
    q = np.clip(np.random.default_rng(0).uniform(-1, 1, model.nq), model.lowerPositionLimit, model.upperPositionLimit)
    kin.update(q)
    pin.framesForwardKinematics(model, data, q)
    for name in ("left_gripper", "right_gripper", "head"):  # both arms and the head
        fid = model.getFrameId(name)
        assert fid < model.nframes, name
        assert np.allclose(kin.frame_pose(name), data.oMf[fid].homogeneous), name
