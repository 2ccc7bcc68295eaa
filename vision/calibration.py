"""Camera-to-base extrinsics from a ChArUco board carried by the arm (eye-to-hand hand-eye calibration).

At each arm pose i the robot gives base_T_gripper[i] (forward kinematics) and the camera sees the
board, giving cam_T_board[i] (solvePnP on the ChArUco corners). The unknowns are base_T_cam (what we
want) and gripper_T_board (how the board is mounted, also unknown):

    base_T_gripper[i] @ gripper_T_board = base_T_cam @ cam_T_board[i]

OpenCV's ``calibrateHandEye`` solves the eye-in-hand form; fed gripper_T_base (the inverses) it
returns base_T_cam for this eye-to-hand case. Its answer seeds a least-squares refinement of both
transforms on the corners' reprojection error over all poses, the quantity the images measure.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from common.errors import AdaptiveHError
from vision.camera_model import Intrinsics
from vision.config import CalibrationConfig
from vision.extrinsics import invert, make_transform


class CalibrationError(AdaptiveHError, RuntimeError):
    """Not enough usable views, or a degenerate set of arm poses."""


@dataclass(frozen=True)
class BoardView:
    """The board's corners seen in one image: 3D in the board frame, 2D in pixels."""

    object_points: np.ndarray  # (N, 3)
    image_points: np.ndarray  # (N, 2)
    cam_T_board: np.ndarray  # 4x4 from solvePnP


@dataclass(frozen=True)
class CalibrationResult:
    base_T_cam: np.ndarray
    gripper_T_board: np.ndarray
    rms_px: float  # reprojection RMS over all corners after refinement
    views: int


class CharucoBoard:
    """The board of ``CalibrationConfig``: its printable image and its detector."""

    def __init__(self, config: CalibrationConfig) -> None:
        self.config = config
        name = config.dictionary
        if not hasattr(cv2.aruco, name):
            raise ValueError(f"unknown ArUco dictionary {name!r} (e.g. DICT_4X4_50, DICT_5X5_100)")
        self.dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
        self.board = cv2.aruco.CharucoBoard(
            (config.squares_x, config.squares_y), config.square_length, config.marker_length, self.dictionary
        )
        self.detector = cv2.aruco.CharucoDetector(self.board)

    @property
    def size(self) -> tuple[float, float]:
        """Board width and height in metres (x along squares_x, y along squares_y)."""
        c = self.config
        return c.squares_x * c.square_length, c.squares_y * c.square_length

    def image(self, pixels_per_square: int = 100) -> np.ndarray:
        """The board as a grey image, no margin: pixel (0, 0) is board point (0, 0), y down."""
        c = self.config
        return self.board.generateImage(
            (c.squares_x * pixels_per_square, c.squares_y * pixels_per_square), marginSize=0
        )

    def detect(self, rgb: np.ndarray, intrinsics: Intrinsics) -> BoardView | None:
        """Corners and board pose in one image, or None with fewer than ``min_corners`` corners."""
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        corners, ids, _, _ = self.detector.detectBoard(grey)
        if ids is None or len(ids) < self.config.min_corners:
            return None
        obj, img = self.board.matchImagePoints(corners, ids)
        obj, img = obj.reshape(-1, 3).astype(np.float64), img.reshape(-1, 2).astype(np.float64)
        K = intrinsics.matrix()
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, None, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            return None
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, None, rvec, tvec)
        return BoardView(obj, img, make_transform(cv2.Rodrigues(rvec)[0], tvec.ravel()))


def _project(K: np.ndarray, cam_T_obj: np.ndarray, points: np.ndarray) -> np.ndarray:
    p = points @ cam_T_obj[:3, :3].T + cam_T_obj[:3, 3]
    uv = p[:, :2] / p[:, 2:3]
    return uv * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]


def _to_vec(T: np.ndarray) -> np.ndarray:
    return np.concatenate([Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]])


def _from_vec(x: np.ndarray) -> np.ndarray:
    return make_transform(Rotation.from_rotvec(x[:3]).as_matrix(), x[3:])


def solve_eye_to_hand(
    base_T_gripper: list[np.ndarray], views: list[BoardView], intrinsics: Intrinsics
) -> CalibrationResult:
    """base_T_cam (and gripper_T_board) from paired arm poses and board views."""
    if len(base_T_gripper) != len(views):
        raise ValueError(f"{len(base_T_gripper)} arm poses but {len(views)} board views")
    if len(views) < 3:
        raise CalibrationError(f"need at least 3 views of the board, got {len(views)}")
    rotations = [Rotation.from_matrix(T[:3, :3]) for T in base_T_gripper]
    spread = max((r.inv() * rotations[0]).magnitude() for r in rotations)
    if np.degrees(spread) < 5:
        raise CalibrationError(
            f"arm orientations span only {np.degrees(spread):.1f} deg; rotate the hand more"
        )
    gripper_T_base = [invert(T) for T in base_T_gripper]
    R_base, t_base = cv2.calibrateHandEye(
        [T[:3, :3] for T in gripper_T_base],
        [T[:3, 3] for T in gripper_T_base],
        [v.cam_T_board[:3, :3] for v in views],
        [v.cam_T_board[:3, 3] for v in views],
        method=cv2.CALIB_HAND_EYE_PARK,
    )
    base_T_cam = make_transform(R_base, t_base)
    # The mount, averaged over views: gripper_T_board = gripper_T_base @ base_T_cam @ cam_T_board.
    mounts = [gTb @ base_T_cam @ v.cam_T_board for gTb, v in zip(gripper_T_base, views, strict=True)]
    mean_rot = Rotation.from_matrix(np.array([T[:3, :3] for T in mounts])).mean().as_matrix()
    gripper_T_board = make_transform(mean_rot, np.mean([T[:3, 3] for T in mounts], axis=0))

    K = intrinsics.matrix()

    def residuals(x: np.ndarray) -> np.ndarray:
        cam_T_base = invert(_from_vec(x[:6]))
        g_T_b = _from_vec(x[6:])
        out = [
            _project(K, cam_T_base @ bTg @ g_T_b, v.object_points) - v.image_points
            for bTg, v in zip(base_T_gripper, views, strict=True)
        ]
        return np.concatenate(out).ravel()

    x0 = np.concatenate([_to_vec(base_T_cam), _to_vec(gripper_T_board)])
    fit = least_squares(residuals, x0, loss="huber", f_scale=1.0, x_scale="jac")
    r = residuals(fit.x).reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum(r**2, axis=1))))
    return CalibrationResult(_from_vec(fit.x[:6]), _from_vec(fit.x[6:]), rms, len(views))
