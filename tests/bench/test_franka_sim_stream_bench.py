"""The franka-sim stream bench runs what sends plans in the config's execution (a learner alone sends none
with the actor as default: the bench once streamed nothing, 0 chunks in the 3 minutes it was watched) and
reads the target from the simulator's truth."""

from __future__ import annotations

import argparse

from repo_scripts import load_script

from deploy.config import load_stack_config


def test_the_bench_config_runs_the_actor_in_the_default_execution_and_reads_the_simulated_target(tmp_path):
    bench = load_script("bench/franka_sim_stream.py")
    args = argparse.Namespace(
        config="configs/franka_sim.yaml", host=bench.HOST, lock_memory="config", minutes=1.0
    )
    cfg = load_stack_config(bench.stack_config(args, tmp_path))
    assert cfg.vision is None and cfg.learner.target_topic == "sim/target_truth"
    assert bench.part_names(cfg) == ["learn", "act"]
    closed = load_stack_config(bench.stack_config(args, tmp_path), learner={"execution": "closed_loop"})
    assert bench.part_names(closed) == ["learn"]
