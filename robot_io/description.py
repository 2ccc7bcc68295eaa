"""Robot descriptions: which arm (a registry keyed by model name) and its URDF in each library's form.

A model's identity (URDF, arm and finger joints, end-effector frame, home pose) is a ``RobotModel`` in
``MODELS``, chosen by name (``robot.model``): ``panda`` (the Franka Emika Robot of the paper, pybullet's
URDF) and ``fr3`` (Franka Research 3, ``robot_io/descriptions/fr3.urdf``, kinematics only; see the NOTICE
there). The two arms share their kinematic chain but not their joint limits, so limits are read from
the model's own URDF, never copied. PyBullet loads the URDF as is (robot_io's PyBullet backend hands
the model to sim's scene). Pinocchio loads the same file and locks the fingers (the arm is what we control).
MuJoCo (for mink) gets a form generated here: visual and collision geometry stripped (IK needs
kinematics only, and MuJoCo cannot resolve ``package://`` mesh paths), finger joints made fixed, and
``fusestatic`` off so the fixed-joint tool-centre-point body survives as a frame.

MuJoCo and Pinocchio are imported where a model is built, so reading a robot config stays light.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pybullet_data

DESCRIPTIONS = Path(__file__).parent / "descriptions"

if TYPE_CHECKING:
    import mujoco
    import pinocchio as pin


@dataclass(frozen=True)
class RobotModel:
    """The identity of one arm model; sim's scene reads these same fields (``sim.panda_scene.SceneRobot``)."""

    name: str
    urdf_path: Path
    arm_joints: tuple[str, ...]
    finger_joints: tuple[str, ...]
    ee_link: str  # the tool centre point frame that IK, FK and the workspace box refer to
    flange_link: str  # the arm's flange, where libfranka's own kinematics end (checked at connect)
    home_q: tuple[float, ...]  # the pose reset and startup go to
    finger_opening: float  # the fingers are held (PyBullet) and locked (Pinocchio) at this opening
    # A Cartesian policy acts on the TCP in the base frame: arms of one kinematic family whose TCPs sit
    # as far beyond the flange (within millimetres) serve the same policy (learner.provenance).
    family: str
    tcp_offset_m: float  # the TCP beyond the flange (tests hold it equal to the URDF's)


MODELS: dict[str, RobotModel] = {
    "panda": RobotModel(
        name="panda",
        urdf_path=Path(pybullet_data.getDataPath()) / "franka_panda" / "panda.urdf",
        arm_joints=tuple(f"panda_joint{i}" for i in range(1, 8)),
        finger_joints=("panda_finger_joint1", "panda_finger_joint2"),
        ee_link="panda_grasptarget",  # 0.105 m beyond the hand flange
        flange_link="panda_link8",
        # A comfortable pose above the table, the usual Panda "ready" configuration.
        home_q=(0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4),
        finger_opening=0.04,
        family="franka",
        tcp_offset_m=0.105,
    ),
    "fr3": RobotModel(
        name="fr3",
        urdf_path=DESCRIPTIONS / "fr3.urdf",
        arm_joints=tuple(f"fr3_joint{i}" for i in range(1, 8)),
        finger_joints=("fr3_finger_joint1", "fr3_finger_joint2"),
        ee_link="fr3_hand_tcp",  # 0.1034 m beyond the flange, as Franka's own end-effector default
        flange_link="fr3_link8",
        # The same "ready" pose: inside the FR3's tighter joint 4 and 6 ranges too.
        home_q=(0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4),
        finger_opening=0.04,
        family="franka",
        tcp_offset_m=0.1034,
    ),
}


def robot_model(name: str) -> RobotModel:
    """The registered model ``name``; a ValueError lists the known ones."""
    if name not in MODELS:
        raise ValueError(f"unknown robot model {name!r}; choose from {sorted(MODELS)}")
    model = MODELS[name]
    if not model.urdf_path.is_file():
        raise FileNotFoundError(f"{model.urdf_path}: the URDF of robot model {name!r} is missing")
    return model


@dataclass(frozen=True)
class JointLimits:
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray


class RobotDescription:
    """Names, limits and the three loaded forms of one arm model (the Panda unless told otherwise)."""

    def __init__(self, model: str = "panda") -> None:
        self.model = robot_model(model)
        self.urdf_path = self.model.urdf_path
        self.arm_joints = self.model.arm_joints
        self.ee_frame = self.model.ee_link

    @cached_property
    def urdf_text(self) -> str:
        return self.urdf_path.read_text()

    @cached_property
    def limits(self) -> JointLimits:
        root = ET.fromstring(self.urdf_text)
        joints = {j.get("name"): j for j in root.iter("joint")}
        lower, upper, velocity = [], [], []
        for name in self.arm_joints:
            limit = joints[name].find("limit")
            lower.append(float(limit.get("lower")))
            upper.append(float(limit.get("upper")))
            velocity.append(float(limit.get("velocity")))
        return JointLimits(np.array(lower), np.array(upper), np.array(velocity))

    def mujoco_xml(self) -> str:
        """The MuJoCo-loadable form of the same URDF (kinematics and inertias only)."""
        root = ET.fromstring(self.urdf_text)
        for link in root.iter("link"):
            for tag in ("visual", "collision"):
                for element in link.findall(tag):
                    link.remove(element)
        for joint in root.iter("joint"):
            if joint.get("name") in self.model.finger_joints:
                joint.set("type", "fixed")
                for element in joint.findall("limit"):
                    joint.remove(element)
        mj = ET.SubElement(root, "mujoco")
        ET.SubElement(
            mj, "compiler", {"fusestatic": "false", "discardvisual": "false", "balanceinertia": "true"}
        )
        return ET.tostring(root, encoding="unicode")

    def mujoco_model(self) -> mujoco.MjModel:
        import mujoco

        model = mujoco.MjModel.from_xml_string(self.mujoco_xml())
        names = [model.joint(i).name for i in range(model.njnt)]
        if names != list(self.arm_joints):
            raise RuntimeError(f"generated MuJoCo model has joints {names}, expected {list(self.arm_joints)}")
        return model

    def pinocchio_model(self) -> pin.Model:
        """Pinocchio model of the arm: the full URDF with the finger joints locked open."""
        import pinocchio as pin

        full = pin.buildModelFromUrdf(str(self.urdf_path))
        lock = [full.getJointId(name) for name in self.model.finger_joints]
        q_ref = pin.neutral(full)
        for jid in lock:
            q_ref[full.joints[jid].idx_q] = self.model.finger_opening
        model = pin.buildReducedModel(full, lock, q_ref)
        if [model.names[i] for i in range(1, model.njoints)] != list(self.arm_joints):
            raise RuntimeError(f"reduced Pinocchio model has joints {list(model.names)[1:]}")
        return model
