"""Hand-eye extrinsics calibration: the solver on exact data, and the whole command in simulation."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from deploy.cli import main
from deploy.config import load_stack_config
from vision.calibration import BoardView, CalibrationError, CharucoBoard, solve_eye_to_hand
from vision.camera_model import Intrinsics
from vision.config import CalibrationConfig
from vision.extrinsics import (
    invert,
    look_at,
    make_transform,
    pose_to_matrix,
    rotation_error_deg,
    translation_error,
)

K = Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5)
TRUE_POSE = look_at((1.3, -0.6, 0.9), (0.5, 0.0, 0.28))


def _synthetic(n: int, spread_deg: float, rng: np.random.Generator):
    """Exact views of board corners for random hand poses around (0.45, 0, 0.4)."""
    base_T_cam = pose_to_matrix(TRUE_POSE)
    gripper_T_board = make_transform(
        Rotation.from_euler("xyz", [170, 10, 30], degrees=True).as_matrix(), [0.02, -0.07, 0.08]
    )
    board = CharucoBoard(CalibrationConfig())
    obj = np.array(board.board.getChessboardCorners(), float)
    poses, views = [], []
    for _ in range(n):
        R = Rotation.from_euler("xyz", [180, 0, 0], degrees=True) * Rotation.from_rotvec(
            np.radians(spread_deg) * rng.uniform(-1, 1, 3)
        )
        base_T_gripper = make_transform(R.as_matrix(), [0.45, 0.0, 0.4] + rng.uniform(-0.1, 0.1, 3))
        cam_T_board = invert(base_T_cam) @ base_T_gripper @ gripper_T_board
        p = obj @ cam_T_board[:3, :3].T + cam_T_board[:3, 3]
        img = p[:, :2] / p[:, 2:3] * [K.fx, K.fy] + [K.cx, K.cy]
        poses.append(base_T_gripper)
        views.append(BoardView(obj, img + rng.normal(0, 0.2, img.shape), cam_T_board))
    return poses, views, base_T_cam, gripper_T_board


def test_solver_recovers_both_transforms_from_noisy_corners():
    poses, views, base_T_cam, gripper_T_board = _synthetic(10, 25, np.random.default_rng(1))
    # Degrade the per-view board poses (as solvePnP noise would): the refinement must fix it.
    noisy = [
        BoardView(
            v.object_points, v.image_points, v.cam_T_board @ make_transform(np.eye(3), [0.003, -0.002, 0.004])
        )
        for v in views
    ]
    res = solve_eye_to_hand(poses, noisy, K)
    assert translation_error(res.base_T_cam, base_T_cam) < 0.002
    assert rotation_error_deg(res.base_T_cam, base_T_cam) < 0.2
    assert translation_error(res.gripper_T_board, gripper_T_board) < 0.003
    assert res.rms_px < 0.5 and res.views == 10


def test_solver_refuses_too_few_views_or_no_rotation():
    poses, views, _, _ = _synthetic(6, 0.5, np.random.default_rng(2))
    with pytest.raises(CalibrationError, match="at least 3 views"):
        solve_eye_to_hand(poses[:2], views[:2], K)
    with pytest.raises(CalibrationError, match="rotate the hand more"):
        solve_eye_to_hand(poses, views, K)


def test_calibrate_command_in_simulation_writes_extrinsics_within_5mm_1deg(tmp_path, capsys):
    """The whole command: board on the Panda's hand, sim camera at its true pose, config starting 7 cm
    and 3 deg off; the written extrinsics are within 5 mm and 1 deg of the truth, other lines kept."""
    wrong = make_transform(
        Rotation.from_euler("z", 3, degrees=True).as_matrix() @ pose_to_matrix(TRUE_POSE)[:3, :3],
        np.array(TRUE_POSE.position) + [0.05, 0.05, -0.0],
    )
    from vision.extrinsics import matrix_to_pose

    start = matrix_to_pose(wrong)
    cfg = {
        "name": "calib",
        "robot": {"backend": "pybullet"},  # another owner's section: must survive untouched
        "vision": {
            "intrinsics": {"width": 320, "height": 240, "fx": 307.5, "fy": 307.5, "cx": 159.5, "cy": 119.5},
            "extrinsics": {"position": list(start.position), "quaternion": list(start.quaternion)},
            "sim": {"pose": {"position": list(TRUE_POSE.position), "quaternion": list(TRUE_POSE.quaternion)}},
            "tracking": {"lost_after_s": 0.4},
        },
    }
    path = tmp_path / "sim.yaml"
    path.write_text("# a comment that must survive\n" + yaml.safe_dump(cfg, sort_keys=False))
    assert main(["calibrate", "--config", str(path), "--views", "8", "--log-level", "WARNING"]) == 0
    out = capsys.readouterr().out
    assert "wrote vision.extrinsics" in out and "error vs the sim camera's true pose" in out
    written = load_stack_config(path).vision
    T = pose_to_matrix(written.extrinsics)
    truth = pose_to_matrix(TRUE_POSE)
    assert translation_error(T, truth) < 0.005 and rotation_error_deg(T, truth) < 1.0
    assert translation_error(wrong, truth) > 0.05  # it did move the estimate
    text = path.read_text()
    assert text.startswith("# a comment that must survive") and "backend: pybullet" in text
    assert written.tracking.lost_after_s == 0.4 and written.sim.pose == TRUE_POSE


def test_the_live_session_poses_the_hand_with_the_configured_arms_kinematics():
    """An FR3 is calibrated with the FR3's kinematics, not the Panda's (the hand pose of every view)."""
    from deploy.commands.calibrate import arm_kinematics
    from robot_io.description import RobotDescription
    from robot_io.kinematics import Kinematics

    settings = load_stack_config("configs/franka_realsense.yaml")
    q = np.array([0.1, -0.6, 0.2, -2.2, 0.1, 1.7, 0.9])
    for model in ("panda", "fr3"):
        arm = settings.robot.model_copy(update={"model": model})
        hand = arm_kinematics(settings.model_copy(update={"robot": arm})).fk(q).homogeneous
        assert np.allclose(hand, Kinematics(RobotDescription(model)).fk(q).homogeneous)
    panda, fr3 = (Kinematics(RobotDescription(name)).fk(q).homogeneous for name in ("panda", "fr3"))
    assert not np.allclose(panda, fr3, atol=1e-4)  # the two arms differ: the wrong one would show
