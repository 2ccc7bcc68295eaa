"""Calibration in simulation: a textured ChArUco board on the Panda's hand, seen by the sim camera.

Gives ``solve_eye_to_hand`` the same inputs a real session does (arm poses from kinematics, images
from the camera) with a known answer: the sim camera's true pose. The board's mount on the hand is
known to the simulation only; the solver estimates it.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np
import pybullet as pb
from scipy.spatial.transform import Rotation

from vision.calibration import BoardView, CharucoBoard
from vision.camera_model import Intrinsics
from vision.cameras.sim import SimRGBDCamera
from vision.config import VisionConfig
from vision.extrinsics import make_transform, matrix_to_pose, pose_to_matrix


class BoardScene(Protocol):
    """What a simulated calibration needs of its scene (``sim.panda_scene.PandaScene`` is one): the arm
    to pose (``robot.home_q``), its hand's pose, and the PyBullet client to put the board in."""

    client_id: int
    robot: Any

    def reset_robot(self, q: np.ndarray | tuple[float, ...] | None = None) -> None: ...

    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]: ...


def _quad_obj(width: float, height: float) -> str:
    """An OBJ of the rectangle [0, w] x [0, h] in z = 0, both sides, UVs so the image is upright.

    Board frame as OpenCV's: x right, y down the printed image, z into the board.
    """
    return "\n".join(
        [
            f"v 0 0 0\nv {width} 0 0\nv {width} {height} 0\nv 0 {height} 0",
            "vt 0 1\nvt 1 1\nvt 1 0\nvt 0 0",
            "vn 0 0 -1\nvn 0 0 1",
            "f 1/1/1 3/3/1 2/2/1\nf 1/1/1 4/4/1 3/3/1",
            "f 1/1/2 2/2/2 3/3/2\nf 1/1/2 3/3/2 4/4/2",
            "",
        ]
    )


class SimBoard:
    """The board as a visual-only body in ``scene``, following the hand with a fixed mount."""

    def __init__(self, scene: BoardScene, board: CharucoBoard, gripper_T_board: np.ndarray) -> None:
        self.scene = scene
        self.gripper_T_board = gripper_T_board
        cid = scene.client_id
        self._dir = tempfile.TemporaryDirectory(prefix="charuco_")
        w, h = board.size
        obj = Path(self._dir.name) / "board.obj"
        obj.write_text(_quad_obj(w, h))
        png = Path(self._dir.name) / "board.png"
        grey = board.image(120)
        cv2.imwrite(str(png), cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
        vis = pb.createVisualShape(pb.GEOM_MESH, fileName=str(obj), physicsClientId=cid)
        self.body = pb.createMultiBody(0, -1, vis, [0, 0, -5], physicsClientId=cid)
        tex = pb.loadTexture(str(png), physicsClientId=cid)
        pb.changeVisualShape(self.body, -1, textureUniqueId=tex, rgbaColor=[1, 1, 1, 1], physicsClientId=cid)

    def follow(self) -> np.ndarray:
        """Put the board where the hand holds it; returns base_T_gripper (what FK would say)."""
        pos, quat = self.scene.ee_pose()
        base_T_gripper = make_transform(Rotation.from_quat(quat).as_matrix(), pos)
        T = base_T_gripper @ self.gripper_T_board
        pose = matrix_to_pose(T)
        pb.resetBasePositionAndOrientation(
            self.body, pose.position, pose.quaternion, physicsClientId=self.scene.client_id
        )
        return base_T_gripper

    def close(self) -> None:
        pb.removeBody(self.body, physicsClientId=self.scene.client_id)
        self._dir.cleanup()


def facing_mount(
    scene: BoardScene, camera: SimRGBDCamera, board: CharucoBoard, offset: float = 0.06
) -> np.ndarray:
    """A mount (gripper_T_board) that shows the board to the camera at the home pose.

    The board hangs ``offset`` m beyond the tool centre point, its face towards the camera, centred.
    """
    scene.reset_robot()
    pos, quat = scene.ee_pose()
    base_T_gripper = make_transform(Rotation.from_quat(quat).as_matrix(), pos)
    cam = pose_to_matrix(camera.pose)
    centre = pos + np.array([0.0, 0.0, -offset]) + 0.1 * (cam[:3, 3] - pos) / np.linalg.norm(cam[:3, 3] - pos)
    z = centre - cam[:3, 3]  # board z points away from the camera (into the board)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 0.0, -1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    w, h = board.size
    R = np.column_stack([x, y, z])
    base_T_board = make_transform(R, centre - R @ [w / 2, h / 2, 0.0])
    return np.linalg.inv(base_T_gripper) @ base_T_board


def collect(
    scene: BoardScene,
    camera: SimRGBDCamera,
    board: CharucoBoard,
    views: int = 12,
    seed: int = 0,
    joint_spread: float = 0.35,
    max_tries: int = 60,
) -> tuple[list[np.ndarray], list[BoardView]]:
    """Move the arm to random poses around home until ``views`` poses show the board."""
    rng = np.random.default_rng(seed)
    sim_board = SimBoard(scene, board, facing_mount(scene, camera, board))
    poses: list[np.ndarray] = []
    seen: list[BoardView] = []
    try:
        for _ in range(max_tries):
            if len(seen) >= views:
                break
            q = np.asarray(scene.robot.home_q) + rng.uniform(-joint_spread, joint_spread, size=7)
            scene.reset_robot(q)
            base_T_gripper = sim_board.follow()
            frame = camera.capture()
            view = board.detect(frame.rgb, frame.intrinsics)
            if view is not None:
                poses.append(base_T_gripper)
                seen.append(view)
    finally:
        sim_board.close()
        scene.reset_robot()
    return poses, seen


def simulated_session(
    vision: VisionConfig, scene: BoardScene, views: int = 12, seed: int = 0, scale: float = 2.0
) -> tuple[list[np.ndarray], list[BoardView], Intrinsics, np.ndarray]:
    """A whole calibration session in simulation: (hand poses, board views, intrinsics, true base_T_cam).

    The board on the Panda's hand in ``scene`` (handed in, e.g. ``tasks.sim_world.replica_scene()``; the
    caller closes it), random arm poses, the sim camera at ``vision.sim_pose()`` rendered at ``scale``
    times the configured size (corners are found more reliably at higher resolution).
    """
    k = vision.intrinsics
    k = k.scaled(round(k.width * scale), round(k.height * scale))
    # The board is a textured quad: PyBullet's TinyRenderer draws textures, the MuJoCo copy does not.
    tiny = vision.sim.model_copy(update={"renderer": "tiny"})
    camera = SimRGBDCamera(scene.client_id, k, vision.sim_pose(), tiny)
    poses, seen = collect(scene, camera, CharucoBoard(vision.calibration), views=views, seed=seed)
    return poses, seen, k, pose_to_matrix(vision.sim_pose())
