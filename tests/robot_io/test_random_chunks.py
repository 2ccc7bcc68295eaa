"""10⁴ random chunks against the workspace box and the joint limits (issue #13): whatever a learner, a
bug or a corrupted message asks for, every commanded configuration stays inside the joint limits (with
the configured margin) and the end effector inside the workspace box. Real PyBullet arm, real IK.

Chunks mix ordinary steps, steps at and past ``max_step_m`` (norm), long pushes into each face and
corner of the box, NaN and empty plans (refused whole), and a few e-stops and releases."""

import numpy as np

from robot_io.controller import RobotController

N_CHUNKS = 10_000
SESSION = "random-chunks"


def random_chunk(rng: np.random.Generator, max_step: float) -> np.ndarray:
    kind = rng.integers(5)
    n = int(rng.integers(1, 4))
    if kind == 0:  # ordinary steps, inside the step bound
        d = rng.uniform(-1.0, 1.0, (n, 3))
        return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1.0) * max_step
    if kind == 1:  # at and past the step bound (refused whole when past it)
        d = rng.normal(size=(n, 3))
        return d / np.linalg.norm(d, axis=1, keepdims=True) * max_step * rng.choice([1.0, 1.5, 10.0])
    if kind == 2:  # a push towards a corner of the box
        return np.tile(rng.choice([-1.0, 1.0], 3) * max_step / np.sqrt(3), (n, 1))
    if kind == 3:  # NaN
        out = rng.uniform(-max_step, max_step, (n, 3))
        out[0, int(rng.integers(3))] = np.nan
        return out
    return np.zeros((0, 3))  # empty


def test_random_chunks_never_leave_the_box_or_the_joint_limits(controller: RobotController):
    rng = np.random.default_rng(13)
    cfg, limits = controller.config, controller.kin.description.limits
    lo, hi = np.asarray(cfg.workspace.lo), np.asarray(cfg.workspace.hi)
    controller.obey(SESSION)
    controller.reset()
    verdicts: dict[str, int] = {}
    worst_box = worst_joint = -np.inf
    seq = 0  # a chunk refused as a bad plan leaves its number free; one queued or met by a hold uses it
    for k in range(N_CHUNKS):
        now = 10.0 + k * cfg.period
        if k % 2500 == 1000:
            controller.operator("estop")
        if k % 2500 == 1100:
            controller.operator("release")
        verdict = controller.push_chunk(SESSION, seq, random_chunk(rng, cfg.max_step_m), now)
        verdicts[verdict] = verdicts.get(verdict, 0) + 1
        seq += verdict in ("accepted", "held")
        state = controller.tick(now).state
        worst_box = max(worst_box, float(np.max(np.maximum(lo - state.ee_pos, state.ee_pos - hi))))
        q = state.q
        worst_joint = max(worst_joint, float(np.max(np.maximum(limits.lower - q, q - limits.upper))))
    print(f"{N_CHUNKS} chunks: {verdicts}; worst box excess {worst_box:.4f} m, joints {worst_joint:.4f} rad")
    assert verdicts["accepted"] > N_CHUNKS // 3 and verdicts["bad_plan"] > N_CHUNKS // 10  # both kinds ran
    assert verdicts["held"] > 0  # and chunks met an e-stopped arm
    assert worst_box <= 0.005  # m: inside the box (PyBullet tracking slack)
    assert worst_joint <= 0.0  # rad: inside the URDF limits
