"""One step cap for the robot, the sender and the plan model (robot_io.step_cap)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from robot_io.step_cap import cap_step_length
from tasks.reach import FACE_VALUE, tracked_step


def test_a_long_step_is_capped_along_its_direction():
    capped = cap_step_length(np.array([[0.05, 0.05, 0.05], [0.01, 0.0, 0.0]]), 0.05)
    np.testing.assert_allclose(np.linalg.norm(capped, axis=1), [0.05, 0.01])
    np.testing.assert_allclose(capped[0], [0.05 / np.sqrt(3)] * 3)
    np.testing.assert_array_equal(cap_step_length(np.zeros(3), 0.05), np.zeros(3))


@given(arrays(float, (4, 3), elements=st.floats(-0.1, 0.1)))
def test_no_step_is_longer_than_the_cap_and_a_short_one_is_unchanged(steps):
    capped = cap_step_length(steps, 0.05)
    assert np.all(np.linalg.norm(capped, axis=1) <= 0.05 * (1 + 1e-12))
    short = np.linalg.norm(steps, axis=1) <= 0.05
    np.testing.assert_array_equal(capped[short], steps[short])


def test_the_plan_model_predicts_the_capped_step():
    """The model's step at face value is the step the robot plays: clipped to the box, then capped."""
    step = np.array([0.05, 0.05, 0.0])
    np.testing.assert_array_equal(tracked_step(step, 0.05, FACE_VALUE), cap_step_length(step, 0.05))
