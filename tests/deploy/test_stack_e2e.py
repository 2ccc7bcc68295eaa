"""The whole stack over Zenoh on loopback: ``adaptiveh up`` with robot-io (PyBullet), vision (sim camera),
monitor and AdaptiveH learning NS Reach, all separate processes; then the recording replays.

Bar (the issue's): the last quarter's success rate above the first quarter's and at least SUCCESS_BAR,
its mean final distance below the first quarter's; retreats happen and at least one retreat's chunk
preempts queued actions on the robot (dropped > 0). Marked slow: `.ci/run` runs it after the default run
(``pytest -m e2e`` runs it alone). It runs configs/sim.yaml's execution: the actor beside the arm since
issue #32 (passing at 7b047f5). Measured earlier in plan execution (the learner making the plans),
10000 steps: distance 0.35 -> 0.033 m, success by quarter 0 / 42 / 90 / 92 %, 1996 retreats of 2158
segments dropping 89,283 planned actions. In the closed loop (6000 steps): 0.41 -> 0.05 m, 0 / 0 / 3 / 73
%. Through the stack, the closed loop's learning took off anywhere from step ~2000 to ~7000 (in-process
NS Reach at the same seed: by 1000-2000; four soaks on 2 cores: ~3500, ~3500, < 10000, 4850-8360; two
8000-step runs of this test in CI never took off, their arm pinned at a workspace wall), so a short run
would make the bar a coin toss: 10000 steps leave the last quarter (7500-10000) after every take-off we
saw.
"""

import json
import subprocess
import sys

import numpy as np
import pytest
from stack_helpers import write_stack_config

from monitor import recording

STEPS = 10000  # about 9 min at 20 Hz
SUCCESS_BAR = 0.2  # last quarter's success rate must reach this, and beat the first quarter's


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(1260)  # 10000 ticks at 20 Hz take ~9 min; its own run's timeout is 1200 s
def test_stack_learns_reach_over_zenoh(tmp_path):
    path, cfg = write_stack_config(tmp_path, "e2e", vision_rate_hz=10.0, steps=STEPS, checkpoint_every=600)
    out = tmp_path / "summary.json"
    proc = subprocess.run(
        [sys.executable, "-m", "deploy.cli", "up", str(path), "--summary", str(out)],
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    s = json.loads(out.read_text())
    res = json.loads((tmp_path / "learner" / "result.json").read_text())
    print(json.dumps(s, indent=1))
    eps = res["episodes"]
    assert s["global_step"] == STEPS and len(eps) == STEPS // cfg["learner"]["max_episode_steps"]
    q = len(eps) // 4
    dist = [e["info"]["distance"] for e in eps]
    succ = [bool(e["success"]) for e in eps]
    first, last = np.mean(dist[:q]), np.mean(dist[-q:])
    print(f"distance first quarter {first:.3f} last quarter {last:.3f}; success {succ[:q]} -> {succ[-q:]}")
    assert last < first
    assert np.mean(succ[-q:]) > np.mean(succ[:q]) and np.mean(succ[-q:]) >= SUCCESS_BAR
    assert s["reasons"].get("retreat", 0) > 10
    assert s["retreat_preemptions"] > 0 and s["retreat_dropped"] > 0
    assert "liveliness" not in s["safety_events"] or s["safety_events"]["liveliness"] <= 1  # only at shutdown
    # The recording holds every part's traffic, typed.
    recs = recording.read(s["recording"])
    kinds = {schema.removeprefix("adaptiveh.") for _, schema, _, _ in recs}
    assert {"RobotState", "Target", "ActionChunk", "ChunkStatus", "RetreatEvent", "LearnerTelemetry"} <= kinds
    assert "Rejected" not in kinds  # every part spoke the schema
    assert s["recording_lost"] == 0  # nothing the recorder missed was gone from the publishers' caches
