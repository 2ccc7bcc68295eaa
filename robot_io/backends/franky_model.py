"""Is the arm at the other end the one our description says, and can the installed franky talk to it?

Our IK, FK and limits come from ``robot.model``'s URDF; libfranka computes the connected arm's own
kinematics (``Robot.model``) and, from robot server version 9 on, hands out the arm's URDF
(``Robot.model_urdf``). At connect we compare them on a few configurations, so a config naming the
wrong arm (or an arm whose kinematics differ from the file) is refused before anything moves:

- flange pose, ours (Pinocchio) vs libfranka's, at fixed configurations inside both arms' limits;
- joint position limits, when the server provides its URDF: ours must lie within the arm's (a wider
  served range is fine, since our IK never leaves ours; a narrower one means commands the arm refuses);
- the arm family implied by the robot server version (5 and below: Panda/FER; 6 and up: FR3), since
  Panda and FR3 share their kinematic chain and only differ in limits.

The server-version table is franky's (doc/compatibility.json: the libfranka release that introduced
each robot server version); franky's wheel bundles one libfranka, named in its shared library.
"""

from __future__ import annotations

import importlib.metadata
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from common.errors import AdaptiveHError
from robot_io.description import RobotDescription

# robot server version -> first libfranka release that speaks it (franky doc/compatibility.json)
SERVER_VERSIONS: dict[int, tuple[int, int, int]] = {
    2: (0, 2, 0), 3: (0, 5, 0), 4: (0, 8, 0), 5: (0, 9, 1), 6: (0, 10, 0),
    7: (0, 13, 3), 8: (0, 14, 1), 9: (0, 15, 0), 10: (0, 18, 0),
}  # fmt: skip
FLANGE_TOLERANCE_M = 1e-3
ROTATION_TOLERANCE_RAD = 1e-2
LIMIT_TOLERANCE_RAD = 1e-2
# Configurations (rad) inside both the Panda's and the FR3's joint ranges.
CHECK_CONFIGURATIONS = np.array(
    [
        [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785],
        [0.5, 0.3, -0.4, -1.8, 0.6, 2.2, -0.9],
        [-1.2, -1.0, 1.0, -0.6, -1.5, 1.0, 2.0],
        [2.0, 1.2, -2.0, -2.9, 2.0, 3.5, -2.5],
    ]
)


class ModelMismatch(AdaptiveHError, RuntimeError):
    """The connected arm is not the configured ``robot.model`` (or its kinematics differ from ours)."""


def libfranka_version() -> tuple[int, int, int] | None:
    """The libfranka release bundled in the installed franky wheel, or None when it cannot be told."""
    try:
        files = importlib.metadata.files("franky-control") or []
    except importlib.metadata.PackageNotFoundError:
        return None
    for f in files:
        found = re.search(r"libfranka[^/]*\.so\.(\d+)\.(\d+)\.(\d+)$", str(f))
        if found:
            return tuple(int(x) for x in found.groups())  # type: ignore[return-value]
    return None


def server_version_for(libfranka: tuple[int, int, int]) -> int:
    """The robot server version a libfranka release speaks."""
    return max(v for v, first in SERVER_VERSIONS.items() if libfranka >= first)


def family_of_server(version: int) -> str:
    """Robot server versions up to 5 are the Panda's (FER, system 4.x); 6 and up are the FR3's."""
    return "panda" if version <= 5 else "fr3"


def parse_incompatible(message: str) -> tuple[int, int] | None:
    """(server, library) versions out of libfranka's IncompatibleVersionException message."""
    found = re.search(r"server version:\s*(\d+),\s*library version:\s*(\d+)", message)
    return (int(found.group(1)), int(found.group(2))) if found else None


@dataclass(frozen=True)
class ModelReport:
    flange_error_m: float
    rotation_error_rad: float
    limits_checked: bool
    server_version: int | None


def urdf_joint_limits(urdf: str) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper limits of the revolute joints of a URDF, in document order (the arm's 7)."""
    root = ET.fromstring(urdf)
    lower, upper = [], []
    for joint in root.iter("joint"):
        limit = joint.find("limit")
        if joint.get("type") == "revolute" and limit is not None:
            lower.append(float(limit.get("lower")))
            upper.append(float(limit.get("upper")))
    return np.array(lower), np.array(upper)


def limits_overreach(
    lower: np.ndarray, upper: np.ndarray, arm_lower: np.ndarray, arm_upper: np.ndarray
) -> tuple[int, float]:
    """The joint (0-based) where our range reaches furthest beyond the arm's, and by how much (rad;
    zero or less when ours lies within the arm's everywhere)."""
    beyond = np.maximum(arm_lower - lower, upper - arm_upper)
    joint = int(np.argmax(beyond))
    return joint, float(beyond[joint])


def verify_model(
    robot: Any, franky: Any, description: RobotDescription, server_version: int | None
) -> ModelReport:
    """Compare the connected arm (a ``franky.Robot``) with ``description``; ModelMismatch if they differ."""
    name = description.model.name
    problems = []
    if server_version is not None and family_of_server(server_version) != name:
        family = family_of_server(server_version)
        problems.append(f"its robot server version {server_version} is an {family.upper()}'s")
    model = pin.buildModelFromUrdf(str(description.urdf_path))
    data = model.createData()
    frame = model.getFrameId(description.model.flange_link)
    arm_idx = [model.joints[model.getJointId(j)].idx_q for j in description.arm_joints]
    identity = franky.Affine()
    worst_p, worst_r = 0.0, 0.0
    for q in CHECK_CONFIGURATIONS:
        full = pin.neutral(model)
        full[arm_idx] = q
        pin.framesForwardKinematics(model, data, full)
        ours = data.oMf[frame]
        theirs = robot.model.pose(franky.Frame.Flange, q, identity, identity)
        worst_p = max(worst_p, float(np.linalg.norm(ours.translation - np.asarray(theirs.translation))))
        rot = np.asarray(theirs.matrix)[:3, :3]
        worst_r = max(worst_r, float(np.linalg.norm(pin.log3(ours.rotation.T @ rot))))
    if worst_p > FLANGE_TOLERANCE_M or worst_r > ROTATION_TOLERANCE_RAD:
        problems.append(
            f"its flange forward kinematics differ from {description.urdf_path.name}'s by up to "
            f"{worst_p * 1000:.1f} mm / {np.degrees(worst_r):.2f} deg over {len(CHECK_CONFIGURATIONS)} poses"
        )
    limits_checked = False
    try:
        urdf = robot.model_urdf
    except Exception:  # servers before version 9 do not serve their URDF
        urdf = ""
    if urdf:
        lower, upper = urdf_joint_limits(urdf)
        mine = description.limits
        if len(lower) >= 7:
            limits_checked = True
            joint, beyond = limits_overreach(mine.lower, mine.upper, lower[:7], upper[:7])
            if beyond > LIMIT_TOLERANCE_RAD:
                problems.append(
                    f"its joint limits are narrower than {name}'s by up to {beyond:.3f} rad "
                    f"(joint {joint + 1}), so our IK could command positions it refuses"
                )
    if problems:
        raise ModelMismatch(
            f"robot.model is {name!r}, but the arm at {robot.fci_hostname} is not: "
            + "; ".join(problems)
            + ". Set robot.model to the connected arm (panda | fr3) or check the arm's configuration."
        )
    return ModelReport(worst_p, worst_r, limits_checked, server_version)


def probe_arm(ip: str, model: str, timeout_s: float = 1.0, connect: bool = True) -> tuple[bool, list[str]]:
    """What ``adaptiveh up --check`` says about a Franka: model, driver, and, with ``connect``
    (``--probe-arm``) when the arm answers, its robot server version, whether the installed franky
    speaks it, and the model check. Moves nothing (connecting claims no motion). Without ``connect``
    nothing goes on the network: a config check must not reach whatever answers at the address."""
    import importlib.util
    import socket

    description = RobotDescription(model)
    lines = [f"robot model {model} ({description.urdf_path.name}, end effector {description.ee_frame})"]
    if importlib.util.find_spec("franky") is None:
        return False, [*lines, "MISSING driver franky: pip install 'adaptiveh[franka]' (franky-control)"]
    lib = libfranka_version()
    ours = server_version_for(lib) if lib else None
    lib_text = ".".join(map(str, lib)) if lib else "unknown"
    dist = importlib.metadata.version("franky-control")
    lines.append(f"driver franky-control {dist} (libfranka {lib_text}, robot server version {ours})")
    if not connect:
        return True, [*lines, f"arm at {ip}: not contacted (add --probe-arm to read its version)"]
    try:
        socket.create_connection((ip, 1337), timeout=timeout_s).close()
    except OSError as exc:
        return True, [*lines, f"arm at {ip}: not reachable ({exc}); its version was not checked"]
    franky = importlib.import_module("franky")
    try:
        robot = franky.Robot(ip, realtime_config=franky.RealtimeConfig.Ignore)
    except franky.IncompatibleVersionException as exc:
        versions = parse_incompatible(str(exc))
        server = versions[0] if versions else None
        family = family_of_server(server).upper() if server else "unknown arm"
        fix = (
            f"pip install franky-control --extra-index-url "
            f"https://timschneider42.github.io/franky/whl/by-robot-server-version/{server}/"
        )
        return False, [
            *lines,
            f"MISMATCH arm at {ip} speaks robot server version {server} ({family}), "
            f"the installed franky speaks {ours}: {fix}",
        ]
    except Exception as exc:  # e.g. FCI not enabled in Desk, or something else listens there
        return True, [*lines, f"WARNING arm at {ip}: connection failed: {type(exc).__name__}: {exc}"]
    family = family_of_server(ours).upper() if ours else "unknown"
    lines.append(f"arm at {ip}: robot server version {ours} ({family}), matches the installed franky")
    try:
        report = verify_model(robot, franky, description, ours)
    except ModelMismatch as exc:
        return False, [*lines, f"MISMATCH {exc}"]
    limits = "joint limits checked" if report.limits_checked else "joint limits not served by this arm"
    lines.append(f"model check: flange FK within {report.flange_error_m * 1000:.2f} mm, {limits}")
    return True, lines
