"""The model check's joint-limit rule on real descriptions: ours must lie within the connected arm's."""

import numpy as np
import pytest

from robot_io.backends.franky_model import LIMIT_TOLERANCE_RAD, limits_overreach, urdf_joint_limits
from robot_io.description import RobotDescription

# Franka's documented FR3 joint-space limits (FCI control parameters; franka_description 1.0.1's
# robots/fr3/joint_limits.yaml): a commanded position beyond them is a reflex on the real arm.
FR3_Q_MAX = np.array([2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159])
FR3_Q_MIN = np.array([-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159])


def test_fr3_limits_are_franka_s_documented_joint_space_limits():
    limits = RobotDescription("fr3").limits
    np.testing.assert_array_equal(limits.lower, FR3_Q_MIN)
    np.testing.assert_array_equal(limits.upper, FR3_Q_MAX)


def test_fr3_lies_within_the_fr3_franky_sim_serves():
    franky_sim = pytest.importorskip("franky_sim")
    served = urdf_joint_limits(franky_sim.FR3_URDF)  # an older franka_description: wider ranges
    mine = RobotDescription("fr3").limits
    _, beyond = limits_overreach(mine.lower, mine.upper, served[0][:7], served[1][:7])
    assert beyond <= 0.0


@pytest.mark.parametrize(("ours", "arm", "joint"), [("panda", "fr3", 6), ("fr3", "panda", 6)])
def test_a_panda_and_an_fr3_overreach_each_other(ours, arm, joint):
    mine = RobotDescription(ours).limits
    theirs = RobotDescription(arm).limits
    worst, beyond = limits_overreach(mine.lower, mine.upper, theirs.lower, theirs.upper)
    assert worst + 1 == joint and beyond > LIMIT_TOLERANCE_RAD
