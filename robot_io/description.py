"""The one Panda description, read from pybullet_data's URDF and turned into each library's form.

PyBullet loads the URDF as is. Pinocchio loads the same file and locks the fingers (the arm is what we
control). MuJoCo (for mink) gets a form generated here: visual and collision geometry stripped (IK needs
kinematics only, and MuJoCo cannot resolve ``package://`` mesh paths), finger joints made fixed, and
``fusestatic`` off so the fixed-joint tool-centre-point body survives as a frame.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cached_property

import mujoco
import numpy as np
import pinocchio as pin

from sim.panda_scene import ARM_JOINTS, EE_LINK, FINGER_JOINTS, panda_urdf_path

FINGER_OPENING = 0.04  # the scene keeps the hand open; Pinocchio locks the fingers here


@dataclass(frozen=True)
class JointLimits:
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray


class PandaDescription:
    """Names, limits and the three loaded forms of the Panda arm."""

    arm_joints = ARM_JOINTS
    ee_frame = EE_LINK

    def __init__(self) -> None:
        self.urdf_path = panda_urdf_path()

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
            if joint.get("name") in FINGER_JOINTS:
                joint.set("type", "fixed")
                for element in joint.findall("limit"):
                    joint.remove(element)
        mj = ET.SubElement(root, "mujoco")
        ET.SubElement(
            mj, "compiler", {"fusestatic": "false", "discardvisual": "false", "balanceinertia": "true"}
        )
        return ET.tostring(root, encoding="unicode")

    def mujoco_model(self) -> mujoco.MjModel:
        model = mujoco.MjModel.from_xml_string(self.mujoco_xml())
        names = [model.joint(i).name for i in range(model.njnt)]
        if names != list(self.arm_joints):
            raise RuntimeError(f"generated MuJoCo model has joints {names}, expected {list(self.arm_joints)}")
        return model

    def pinocchio_model(self) -> pin.Model:
        """Pinocchio model of the arm: the full URDF with the finger joints locked open."""
        full = pin.buildModelFromUrdf(str(self.urdf_path))
        lock = [full.getJointId(name) for name in FINGER_JOINTS]
        q_ref = pin.neutral(full)
        for jid in lock:
            q_ref[full.joints[jid].idx_q] = FINGER_OPENING
        model = pin.buildReducedModel(full, lock, q_ref)
        if [model.names[i] for i in range(1, model.njoints)] != list(self.arm_joints):
            raise RuntimeError(f"reduced Pinocchio model has joints {list(model.names)[1:]}")
        return model
