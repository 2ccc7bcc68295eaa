"""The workspace box as a limit of the IK's QP, so that a goal at a wall gives a motion along it.

Without it the IK reaches a clipped goal on a path that leaves the box by a millimetre or so (the tool's
orientation and the posture task pull it off the straight line), the command check refuses that
command, and the arm holds still at the wall for as long as the action keeps any component into it.
"""

from __future__ import annotations

import mink
import mujoco
import numpy as np


class WorkspaceLimit(mink.Limit):
    """Keeps a body's origin in the axis-aligned box ``[lo, hi]``, linearised as mink's configuration
    limit is: ``J Δq ≤ gain (hi - p)`` and ``-J Δq ≤ gain (p - lo)``. Outside the box it asks for a way
    back of at most ``max_return`` per step: a step that slides along a wall curves outwards (second
    order), and unless the next one returns those drifts add up; a start far outside must not make the
    QP infeasible."""

    def __init__(
        self,
        model: mujoco.MjModel,
        body: str,
        lo: np.ndarray,
        hi: np.ndarray,
        max_return: float,
        gain: float = 0.95,
    ) -> None:
        self.model = model
        self.body_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
        if self.body_id < 0:
            raise ValueError(f"no body {body!r} in the IK's model")
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        if self.lo.shape != (3,) or self.hi.shape != (3,) or np.any(self.lo >= self.hi):
            raise ValueError(f"the workspace box needs lo < hi on each axis, got {lo} and {hi}")
        self.max_return, self.gain = max_return, gain

    def compute_qp_inequalities(self, configuration: mink.Configuration, dt: float) -> mink.Constraint:
        del dt  # a position limit: the bound is on the displacement, whatever the step's duration
        jacp = np.empty((3, self.model.nv))
        mujoco.mj_jacBody(self.model, configuration.data, jacp, None, self.body_id)
        p = configuration.data.xpos[self.body_id]
        room = self.gain * np.concatenate([self.hi - p, p - self.lo])
        return mink.Constraint(G=np.vstack([jacp, -jacp]), h=np.maximum(room, -self.max_return))
