"""``adaptiveh calibrate``: estimate the camera-to-base extrinsics from a ChArUco board on the hand.

``--config`` with ``vision.camera: sim`` runs the whole session in simulation (the board on the
Panda's hand, random arm poses, the sim camera at ``vision.sim.pose``) and reports the error against
that true pose. With ``realsense`` it is interactive: move the arm (hand-guiding or jog) so the board
is seen from varied orientations and press Enter at each pose; the arm's joint angles come from the
robot-io process's ``state`` (Zenoh) and the hand pose from the kinematics. The result is written to
the config's ``vision.extrinsics`` unless ``--dry-run``.
"""

from __future__ import annotations

import argparse
import logging
import re
import threading
from pathlib import Path

import numpy as np

from deploy.commands import setup_logging

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("calibrate", help="camera-to-base extrinsics from a ChArUco board on the hand")
    p.add_argument("--config", default="configs/sim.yaml", help="top-level YAML (name, zenoh, vision)")
    p.add_argument("--views", type=int, default=12, help="board views to use (at least 3)")
    p.add_argument("--seed", type=int, default=0, help="sim only: random arm poses")
    p.add_argument(
        "--scale", type=float, default=2.0, help="sim only: render at this multiple of the configured size"
    )
    p.add_argument("--dry-run", action="store_true", help="print the result, do not write the config")
    p.add_argument("--log-level", default="INFO")
    p.set_defaults(func=run)


def write_extrinsics(path: str | Path, position: tuple[float, ...], quaternion: tuple[float, ...]) -> None:
    """Replace ``vision.extrinsics`` in the YAML text, keeping every other line (and comment) as it is."""
    path = Path(path)
    lines = path.read_text().splitlines(keepends=True)
    vision = next((i for i, line in enumerate(lines) if re.match(r"^vision:\s*(#.*)?$", line)), None)
    if vision is None:
        raise ValueError(f"{path}: no top-level 'vision:' section to write the extrinsics into")
    end = next((i for i in range(vision + 1, len(lines)) if re.match(r"^\S", lines[i])), len(lines))
    block = [
        "  extrinsics:                    # camera-to-base, written by `adaptiveh calibrate`\n",
        f"    position: [{', '.join(f'{x:.6f}' for x in position)}]\n",
        f"    quaternion: [{', '.join(f'{x:.6f}' for x in quaternion)}]\n",
    ]
    start = next((i for i in range(vision + 1, end) if re.match(r"^  extrinsics:", lines[i])), None)
    if start is None:
        lines[vision + 1 : vision + 1] = block
    else:
        stop = start + 1
        while stop < end and (re.match(r"^   ", lines[stop]) or not lines[stop].strip()):
            stop += 1
        lines[start:stop] = block
    path.write_text("".join(lines))


def _sim_session(settings, args) -> tuple[list, list, object, np.ndarray | None]:
    from tasks.sim_world import replica_scene
    from vision.calibration_sim import simulated_session

    with replica_scene(args.seed) as scene:
        return simulated_session(settings.vision, scene, args.views, args.seed, args.scale)


def arm_kinematics(settings):  # noqa: ANN001, ANN201 (imports kept lazy: the command starts fast)
    """The kinematics of the arm the config names (``robot.model``): the hand pose of each view."""
    from robot_io.description import RobotDescription
    from robot_io.kinematics import Kinematics

    return Kinematics(RobotDescription(settings.robot.model))


def _live_session(settings, args) -> tuple[list, list, object, None]:
    from bus import messages as m
    from bus.transport import Bus, open_session
    from vision.calibration import CharucoBoard
    from vision.cameras.realsense import RealSenseCamera

    board = CharucoBoard(settings.vision.calibration)
    kin = arm_kinematics(settings)
    latest: list[m.RobotState] = []
    got = threading.Event()

    def on_state(s: m.RobotState) -> None:
        latest[:] = [s]
        got.set()

    bus = Bus(open_session(settings.zenoh), settings.name)
    camera = RealSenseCamera(settings.vision.realsense)
    poses, views = [], []
    try:
        bus.subscribe(m.STATE, on_state)
        if not got.wait(10.0):
            raise RuntimeError(
                f"no robot state on {bus.key(m.STATE)} within 10 s: is `adaptiveh robot-io` running?"
            )
        while len(views) < args.views:
            answer = input(f"[{len(views)}/{args.views}] move the arm, Enter to capture, q to finish: ")
            if answer.strip().lower() == "q":
                break
            frame = camera.capture()
            q = np.asarray(latest[0].q)
            view = board.detect(frame.rgb, frame.intrinsics)
            if view is None:
                print("  board not found (need the board in view, sharp, well lit)")
                continue
            poses.append(kin.fk(q).homogeneous)
            views.append(view)
            print(f"  {len(view.object_points)} corners")
        return poses, views, camera.intrinsics, None
    finally:
        camera.close()
        bus.close()


def run(args: argparse.Namespace) -> int:
    from deploy.config import load_stack_config
    from vision.calibration import CalibrationError, solve_eye_to_hand
    from vision.extrinsics import matrix_to_pose, rotation_error_deg, translation_error

    setup_logging(args.log_level)
    settings = load_stack_config(args.config)
    if settings.vision is None:
        log.error("%s: no vision section (the camera and the board to calibrate)", args.config)
        return 2
    session = _sim_session if settings.vision.camera == "sim" else _live_session
    poses, views, intrinsics, truth = session(settings, args)
    try:
        result = solve_eye_to_hand(poses, views, intrinsics)
    except CalibrationError as exc:
        log.error("calibration failed: %s", exc)
        return 1
    pose = matrix_to_pose(result.base_T_cam)
    print(f"views: {result.views}, reprojection RMS {result.rms_px:.2f} px")
    position, quaternion = np.round(pose.position, 4).tolist(), np.round(pose.quaternion, 5).tolist()
    print(f"camera-to-base: position {position} quaternion {quaternion}")
    if truth is not None:
        mm = 1000 * translation_error(result.base_T_cam, truth)
        deg = rotation_error_deg(result.base_T_cam, truth)
        print(f"error vs the sim camera's true pose: {mm:.2f} mm, {deg:.3f} deg")
    if not args.dry_run:
        write_extrinsics(args.config, pose.position, pose.quaternion)
        print(f"wrote vision.extrinsics to {args.config}")
    return 0
