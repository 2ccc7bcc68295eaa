"""One description, three loaders: PyBullet, Pinocchio and MuJoCo agree on the end effector."""

import mujoco
import numpy as np
import pybullet as pb

from robot_io.description import RobotDescription
from robot_io.kinematics import Kinematics
from sim.panda_scene import PandaScene, panda_urdf_path


def test_urdf_comes_from_pybullet_data():
    path = panda_urdf_path()
    assert path.parts[-3:] == ("pybullet_data", "franka_panda", "panda.urdf")


def test_fk_agrees_within_1mm_over_100_random_configurations():
    desc = RobotDescription()
    kin = Kinematics(desc)
    model = desc.mujoco_model()
    data = mujoco.MjData(model)
    ee_body = model.body(desc.ee_frame).id
    rng = np.random.default_rng(0)
    lo, hi = desc.limits.lower, desc.limits.upper
    with PandaScene(motion="static") as scene:
        worst = 0.0
        worst_rot = 0.0
        for _ in range(100):
            q = rng.uniform(lo, hi)
            for j, qj in zip(scene.arm_joints, q, strict=True):
                pb.resetJointState(scene.robot_id, j, qj, physicsClientId=scene.client_id)
            p_pb, quat_pb = scene.ee_pose()
            oMf = kin.fk(q)
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            p_mj = data.xpos[ee_body]
            worst = max(worst, np.linalg.norm(p_pb - oMf.translation), np.linalg.norm(p_mj - oMf.translation))
            r_pb = np.array(pb.getMatrixFromQuaternion(quat_pb)).reshape(3, 3)
            r_mj = data.xmat[ee_body].reshape(3, 3)
            worst_rot = max(worst_rot, np.abs(r_pb - oMf.rotation).max(), np.abs(r_mj - oMf.rotation).max())
    assert worst < 1e-3, f"end-effector positions disagree by {worst * 1000:.3f} mm"
    assert worst_rot < 1e-3


def test_mujoco_form_is_generated_from_the_urdf():
    desc = RobotDescription()
    xml = desc.mujoco_xml()
    assert "package://" not in xml and "<visual" not in xml  # meshes stripped, kinematics kept
    model = desc.mujoco_model()
    assert model.nq == 7
    np.testing.assert_allclose(model.jnt_range[:, 0], desc.limits.lower)
    np.testing.assert_allclose(model.jnt_range[:, 1], desc.limits.upper)


def test_robot_io_panda_model_is_the_scene_s_standalone_panda():
    """sim cannot import robot_io, so a scene built without it carries its own Panda; they must agree."""
    from typing import get_args

    from robot_io.config import MotionPreset
    from robot_io.description import MODELS, robot_model
    from sim.panda_scene import MotionPreset as SceneMotionPreset
    from sim.panda_scene import StandalonePanda

    model, standalone = robot_model("panda"), StandalonePanda()
    for field in ("urdf_path", "arm_joints", "finger_joints", "ee_link", "home_q"):
        assert getattr(model, field) == getattr(standalone, field), field
    assert set(get_args(MotionPreset)) == set(get_args(SceneMotionPreset))
    assert set(MODELS) >= {"panda"}


def test_unknown_robot_model_names_the_known_ones():
    import pytest

    from robot_io.description import robot_model

    with pytest.raises(ValueError, match="panda"):
        robot_model("ur5")
