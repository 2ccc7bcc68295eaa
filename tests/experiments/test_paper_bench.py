"""The paper pipeline on a tiny budget: every run (6 methods, SAC and PPO included), figure and summary
field produced, finite, resumable; each method's cost in the summary and the printed table."""

from __future__ import annotations

import json
import math
import platform
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from paper_tiny import STEPS, TINY  # noqa: E402

from deploy.cli import build_parser  # noqa: E402
from experiments import stats  # noqa: E402
from experiments.execute import X86_LEVELS, cpu_description, execute_run  # noqa: E402
from experiments.machines import machine_of, machines, mixed_machines  # noqa: E402
from experiments.metrics import run_metrics  # noqa: E402
from experiments.paper import main_paper  # noqa: E402
from experiments.plan import (  # noqa: E402
    ENVS,
    PAPER_ALGOS,
    SPEED_ENVS,
    Plan,
    RunSpec,
    agent_config,
    build_plan,
    env_kwargs,
)
from experiments.report import finite_leaves  # noqa: E402
from experiments.tables import format_cost  # noqa: E402
from learner.registry import ALGOS  # noqa: E402

X86 = platform.machine() in ("x86_64", "AMD64")
FIGURES = ("main_results.png", "fast_comparison.png", "h_window.png", "summary_bars.png")
# The first test here sets up the 48-run tiny plan (conftest.tiny_run): 2-4 min on 2 free cores, over
# the 600 s default on a machine shared with other work (measured: 447 s at load 4).
pytestmark = pytest.mark.timeout(1800)


def _finite_stat(stat: dict) -> None:
    assert stat["n"] == 2
    for key in ("mean", "lo", "hi"):
        assert isinstance(stat[key], float) and math.isfinite(stat[key]), stat
    assert stat["lo"] - 1e-9 <= stat["mean"] <= stat["hi"] + 1e-9


CPUINFO = Path("/proc/cpuinfo")
# The kernel's names for what numpy requires of each x86 level, cumulative (its test_cpu_features' groups).
LEVEL_FLAGS = {
    "X86_V2": {"sse", "sse2", "pni", "ssse3", "sse4_1", "sse4_2", "popcnt", "cx16", "lahf_lm"},
    "X86_V3": {"avx", "avx2", "f16c", "fma", "bmi1", "bmi2", "abm", "movbe"},
    "X86_V4": {"avx512f", "avx512cd", "avx512vl", "avx512bw", "avx512dq"},
}


@pytest.mark.skipif(not X86 or not CPUINFO.is_file(), reason="reads the x86 flags in /proc/cpuinfo")
def test_a_run_names_the_simd_level_of_its_cpu() -> None:
    """The level a run records is the highest whose features the kernel lists for this CPU."""
    flags = set(next(ln for ln in CPUINFO.read_text().splitlines() if ln.startswith("flags")).split())
    expected, needed = None, set()
    for level in reversed(X86_LEVELS):  # lowest first: each level needs the ones below
        needed |= LEVEL_FLAGS[level]
        if needed <= flags:
            expected = level
    cpu = cpu_description()
    assert cpu["simd"] == expected and (expected is None or expected in X86_LEVELS), (cpu, expected)
    assert cpu["model"]


def test_a_setting_whose_runs_span_cpus_is_named_mixed() -> None:
    """One front drawn on two SIMD levels, or beside runs that do not say, is not one machine's."""
    v4, v3 = {"model": "EPYC", "simd": "X86_V4"}, {"model": "EPYC", "simd": "X86_V3"}
    runs = {
        "a0": {"env": "a", "cpu": v4},
        "a1": {"env": "a", "cpu": v4},
        "b0": {"env": "b", "cpu": v4},
        "b1": {"env": "b", "cpu": v3},
        "c0": {"env": "c", "cpu": v4},
        "c1": {"env": "c"},
    }
    counts = machines(runs)
    assert counts["a"] == {"EPYC (X86_V4)": 2} and counts["c"] == {"EPYC (X86_V4)": 1, "unrecorded": 1}
    assert mixed_machines(counts) == ["b", "c"]


def test_every_run_finishes_with_its_own_file(tiny_run: tuple[Path, dict]) -> None:
    out, summary = tiny_run
    assert summary["failed_runs"] == [] and summary["missing_runs"] == [] and summary["stale_runs"] == []
    assert (
        summary["plan"]["runs_total"] == summary["plan"]["runs_finished"] == 2 * len(ENVS) * len(PAPER_ALGOS)
    )
    files = sorted((out / "runs").glob("*.json"))
    assert len(files) == summary["plan"]["runs_total"]
    for path in files:
        run = json.loads(path.read_text())
        assert run["global_step"] == STEPS  # equal budgets, exactly
        assert run["executor"] == "local" and TINY.get(run["algo"], {}).items() <= run["config"].items()
        assert 0 < run["wall_s"] and 20 < run["peak_rss_mb"] < 8000
        assert run["packages"]["numpy"] == np.__version__ and run["packages"]["gymnasium"] == gym.__version__
        assert run["cpu"] == cpu_description() and (run["cpu"]["simd"] is not None or not X86)
        steps = run["episodes"]["global_step"]
        assert steps and steps == sorted(steps) and steps[-1] <= STEPS
        assert len(run["episodes"]["ret"]) == len(steps)
        if run["algo"] in ("adaptiveh", "rkhs"):
            assert run["segments"]["H"] and sum(run["segments"]["H"]) <= STEPS
        if run["algo"] == "rkhs":
            assert max(run["segments"]["H"]) <= run["config"].get("fixed_h", 10)
        if run["env"].startswith("cartpole"):
            assert "gravity" in run["episodes"]["info"]
        if run["env"].startswith("reach"):
            assert all(s is not None for s in run["episodes"]["success"])


def test_summary_fields_exist_and_are_finite(tiny_run: tuple[Path, dict]) -> None:
    out, summary = tiny_run
    on_disk = json.loads((out / "summary.json").read_text())
    assert finite_leaves(on_disk) == []
    assert set(on_disk["groups"]) == set(ENVS)
    for env, by_algo in on_disk["groups"].items():
        assert set(by_algo) == set(PAPER_ALGOS)
        for algo, g in by_algo.items():
            assert g["n_runs"] == 2 and g["seeds"] == [0, 1], (env, algo)
            for key in (
                "return_mean",
                "final_return",
                "steps_to_threshold",
                "wall_s",
                "steps_per_s",
                "peak_rss_mb",
            ):
                _finite_stat(g[key])
            assert 0.0 <= g["reached_fraction"] <= 1.0
            curve = g["curve"]
            assert curve["n"] == 2 and len(curve["steps"]) >= 1
            assert len(curve["steps"]) == len(curve["mean"]) == len(curve["lo"]) == len(curve["hi"])
            assert all(math.isfinite(v) for v in curve["mean"] + curve["lo"] + curve["hi"])
    for env in SPEED_ENVS:
        h = on_disk["H"][env]
        assert h["n"] == 2 and h["segments"] > 0
        _finite_stat(h["mean_H"])
        assert abs(sum(h["histogram"]["fraction"]) - 1.0) < 1e-9
        assert h["evolution"]["steps"] and len(h["evolution"]["mean"]) == len(h["evolution"]["steps"])
    claims = {
        "outperforms_td3_ddpg",
        "outperforms_sac_ppo",
        "faster_convergence",
        "h_narrows_when_faster",
        "level_with_best_off_policy",
    }
    assert claims <= set(on_disk["verdicts"])
    for claim in claims:
        verdict = on_disk["verdicts"][claim]["verdict"]
        assert verdict.split(" (")[0] in ("confirmed", "partly confirmed", "not confirmed")
        for comp in on_disk["verdicts"][claim]["comparisons"].values():
            assert comp["outcome"] in ("better", "tie", "worse")
            if claim != "h_narrows_when_faster":  # AdaptiveH against a rival: both seeds pair up
                assert comp["paired"]["n_a"] == 2 and comp["paired"]["outcome"] in ("better", "tie", "worse")
    assert set(on_disk["per_run"]) == {p.stem for p in (out / "runs").glob("*.json")}
    assert sum(on_disk["code_commits"].values()) == len(on_disk["per_run"])  # every run names its commit
    assert "None" not in on_disk["code_commits"]
    here = machine_of({"cpu": cpu_description()})  # every run was made here, on this one CPU
    assert on_disk["machines"] == {env: {here: 2 * len(PAPER_ALGOS)} for env in sorted(ENVS)}
    assert mixed_machines(on_disk["machines"]) == []
    level = on_disk["verdicts"]["level_with_best_off_policy"]["comparisons"]
    assert len(level) == len(ENVS) and all(k.split(":")[1] in ("td3", "ddpg", "sac") for k in level)
    assert all(c["decided_on"] == "paired" for c in level.values())
    table = (out / on_disk["tables"]).read_text()
    # one row per setting in the results table, one in the cost table
    assert table.count("| AdaptiveH |") == len(ENVS) + 1 and "## Verdicts" in table and "nan" not in table
    assert "## Cost per method" in table and "| SAC | 8 |" in table and "| PPO | 8 |" in table


def test_cost_of_each_method_in_summary_and_printed_table(tiny_run: tuple[Path, dict]) -> None:
    out, summary = tiny_run
    cost = json.loads((out / "summary.json").read_text())["cost"]
    assert list(cost) == list(PAPER_ALGOS)
    runs = [json.loads(p.read_text()) for p in (out / "runs").glob("*.json")]
    for algo, c in cost.items():
        mine = [r for r in runs if r["algo"] == algo]
        assert c["runs"] == len(mine) == 2 * len(ENVS)
        assert c["wall_s_total"] == pytest.approx(sum(r["wall_s"] for r in mine))
        assert c["steps_per_s"] == pytest.approx(sum(r["global_step"] for r in mine) / c["wall_s_total"])
        assert c["peak_rss_mb_max"] == pytest.approx(max(r["peak_rss_mb"] for r in mine))
        assert 20 < c["peak_rss_mb"] <= c["peak_rss_mb_max"] < 8000
        assert set(c["by_env"]) == set(ENVS)
        for env, e in c["by_env"].items():
            assert e["runs"] == 2 and e["wall_vs_td3"] > 0, (algo, env)
        assert c["wall_vs_td3_min"] <= c["wall_vs_td3_max"]
    assert all(e["wall_vs_td3"] == pytest.approx(1.0) for e in cost["td3"]["by_env"].values())
    printed = format_cost(summary).splitlines()
    assert printed[0].startswith("Cost per method")
    for label in ("AdaptiveH", "TD3", "DDPG", "SAC", "PPO", "RKHS fixed-H"):
        row = next(line for line in printed if line.startswith(label + " "))
        assert row.split()[len(label.split())] == str(2 * len(ENVS)) and "—" not in row


@pytest.mark.parametrize(("algo", "steps"), [("sac", 300), ("ppo", 1100)])
def test_sac_and_ppo_run_the_zoo_values_through_the_bench_run_function(
    tmp_path: Path, algo: str, steps: int
) -> None:
    """Each new baseline, with the zoo's values (no overrides), through the runner's per-run function:
    SAC past its learning_starts (100), PPO past one whole rollout (n_steps 1024) and its update."""
    env = ENVS["pendulum_slow"]
    spec = RunSpec("pendulum_slow", algo, 0, steps, agent_config(env, algo), env_kwargs(env, 0))
    assert spec.config == {}  # zoo values: the defaults of learner.baselines' config classes
    res = execute_run(spec, str(tmp_path))
    assert "error" not in res, res.get("error")
    run = json.loads((tmp_path / "runs" / f"pendulum_slow__{algo}__s0__{steps}.json").read_text())
    assert run["algo"] == algo and run["global_step"] == steps and run["seed"] == 0
    assert run["episodes"]["global_step"] == list(range(200, steps + 1, 200))  # 200-step episodes
    assert all(-2000 < r < 0 for r in run["episodes"]["ret"])
    assert run["wall_s"] > 0 and 20 < run["peak_rss_mb"] < 8000 and run["steps_per_s"] > 0
    assert "noise_bound" in run["episodes"]["info"] and run["metrics"]["final_return"] is not None


def test_figures_are_real_pngs(tiny_run: tuple[Path, dict]) -> None:
    import matplotlib.image as mpimg

    out, summary = tiny_run
    assert sorted(summary["figures"]) == sorted(FIGURES)
    for name in FIGURES:
        img = mpimg.imread(out / name)
        assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 300
        assert float(np.std(img)) > 0.01  # not a blank canvas


def test_finished_runs_are_never_recomputed_and_partial_sets_report(tiny_run: tuple[Path, dict]) -> None:
    out, _ = tiny_run
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.json")}
    again = main_paper(quick=True, out=out, jobs=2, seeds=2, steps=STEPS, overrides=TINY, progress=False)
    assert again["last_invocation"]["ran"] == 0
    assert again["last_invocation"]["skipped"] == len(stamps)
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.json")} == stamps

    # A partial set (as while the full experiment is still running) still yields every figure, with
    # the missing runs named and the incomplete groups counted.
    partial = out / "partial"
    (partial / "runs").mkdir(parents=True)
    for name in stamps:
        if "__s1__" not in name and "reach_slow__td3" not in name:
            (partial / "runs" / name).write_bytes((out / "runs" / name).read_bytes())
    summary = main_paper(
        quick=True, out=partial, jobs=1, seeds=2, steps=STEPS, report_only=True, progress=False
    )
    assert summary["last_invocation"]["ran"] == 0
    assert len(summary["missing_runs"]) == len(ENVS) * len(PAPER_ALGOS) + 1
    assert f"reach_slow__td3__s0__{STEPS}" in summary["missing_runs"]
    assert summary["groups"]["reach_slow"]["td3"]["n_runs"] == 0
    assert summary["groups"]["reach_slow"]["td3"]["final_return"]["mean"] is None
    assert summary["groups"]["cartpole_slow"]["adaptiveh"]["n_runs"] == 1
    outcome = summary["verdicts"]["outperforms_td3_ddpg"]["comparisons"]["reach_slow:td3"]["outcome"]
    assert outcome == "missing"
    assert summary["verdicts"]["outperforms_td3_ddpg"]["verdict"] == "no data"  # one seed decides nothing
    assert all((partial / f).is_file() for f in FIGURES)
    assert finite_leaves(json.loads((partial / "summary.json").read_text())) == []


def test_run_metrics_definitions() -> None:
    # Episodes ending at steps 100..1000 with returns 10, 20, ..., 100; budget 1000, threshold 55.
    steps = list(range(100, 1001, 100))
    rets = [float(r) for r in range(10, 101, 10)]
    m = run_metrics(steps, rets, 1000, 55.0)
    assert m["return_mean"] == pytest.approx(55.0)
    assert m["final_return"] == pytest.approx(100.0)  # only the episode ending at 1000 is in the last 10%
    # trailing mean of 5 episodes first >= 55 at the 8th episode: (40+50+60+70+80)/5 = 60 (7th: 50)
    assert m["steps_to_threshold"] == 800 and m["reached"] is True
    never = run_metrics(steps, rets, 1000, 1e9)
    assert never["steps_to_threshold"] == 1000 and never["reached"] is False
    assert m["curve"][0] is None  # no episode has ended by step 20
    assert m["curve"][-1] == pytest.approx(80.0)


def test_bootstrap_interval() -> None:
    x = [1.0, 2.0, 3.0, 4.0, 5.0]
    s = stats.bootstrap_mean(x)
    assert s["mean"] == 3.0 and 1.0 < s["lo"] < 3.0 < s["hi"] < 5.0
    assert stats.bootstrap_mean([7.0]) == {"mean": 7.0, "lo": 7.0, "hi": 7.0, "n": 1}
    assert stats.bootstrap_mean([])["mean"] is None
    d = stats.bootstrap_diff([10.0, 11.0, 12.0], [1.0, 2.0, 3.0])
    assert d["diff"] == pytest.approx(9.0) and d["lo"] > 0
    assert stats.outcome(d) == "better" and stats.outcome(d, higher_is_better=False) == "worse"
    assert stats.outcome(stats.bootstrap_diff([1.0, 5.0], [2.0, 4.0])) == "tie"


def test_paired_difference_sees_a_deficit_in_every_world_that_the_unpaired_one_calls_a_tie() -> None:
    """NS Pendulum's shape in results/paper: worlds (seeds) differ by far more than the methods do."""
    worlds = {0: -180.0, 1: -110.0, 2: -250.0, 3: -140.0, 4: -210.0}
    ours = {k: v - 40.0 - 5.0 * k for k, v in worlds.items()}
    unpaired = stats.bootstrap_diff(list(ours.values()), list(worlds.values()))
    paired = stats.bootstrap_paired_diff(ours, worlds)
    assert paired["diff"] == pytest.approx(unpaired["diff"]) == pytest.approx(-50.0)
    assert stats.outcome(unpaired) == "tie" and stats.outcome(paired) == "worse"
    assert paired["n_a"] == paired["n_b"] == 5
    # only the seeds both ran pair up; none in common is no data
    assert stats.bootstrap_paired_diff({0: 1.0, 1: 2.0}, {1: 0.0, 2: 5.0})["n_a"] == 1
    assert stats.bootstrap_paired_diff({0: 1.0}, {1: 0.0})["diff"] is None


def test_level_with_the_best_is_decided_on_the_paired_difference() -> None:
    """A deficit in every world is "worse" (not level) even where the unpaired interval is a tie; the
    best rival is the one with the highest mean."""
    from experiments.verdicts import verdicts

    worlds = [-180.0, -110.0, -250.0, -140.0, -210.0]
    returns = {
        "adaptiveh": [w - 40.0 - 5.0 * k for k, w in enumerate(worlds)],
        "sac": worlds,
        "td3": [w - 3.0 for w in worlds],
    }
    specs = [RunSpec("pendulum_slow", a, k, 100) for a in returns for k in range(5)]
    metrics = ("final_return", "return_mean", "steps_to_threshold")  # every claim reads one of these
    runs = {
        r.name: {"seed": r.seed, "metrics": dict.fromkeys(metrics, returns[r.algo][r.seed])} for r in specs
    }
    plan = Plan(specs, ["pendulum_slow"], list(returns), list(range(5)), {"pendulum_slow": 100}, False)
    level = verdicts(plan, runs, {})["level_with_best_off_policy"]
    comp = level["comparisons"]["pendulum_slow:sac"]
    assert comp["unpaired_outcome"] == "tie" and comp["paired"]["outcome"] == "worse"
    assert comp["outcome"] == "worse" and comp["decided_on"] == "paired"
    assert level["verdict"].startswith("not confirmed")


def test_plan_orders_cheap_runs_first_then_seed_major_with_equal_budgets() -> None:
    plan = build_plan()
    assert len(plan.runs) == 5 * len(ENVS) * len(PAPER_ALGOS)
    assert len(set(plan.runs)) == len(plan.runs)
    cheap = [r.algo in ("adaptiveh", "rkhs") and not r.env.startswith("reach") for r in plan.runs]
    n_cheap = sum(cheap)
    assert n_cheap == 5 * 3 * 2 and all(cheap[:n_cheap])  # RKHS learners on CartPole x2, Pendulum first
    rest = plan.runs[n_cheap:]
    assert [r.seed for r in rest] == sorted(r.seed for r in rest)
    first_seed1 = next(i for i, r in enumerate(rest) if r.seed == 1)
    assert {(r.env, r.algo) for r in rest[:first_seed1]} == {
        (e, a) for e in ENVS for a in PAPER_ALGOS if not (a in ("adaptiveh", "rkhs") and e != "reach_slow")
    }
    for env in ENVS:
        assert {r.steps for r in plan.runs if r.env == env} == {ENVS[env].steps}
    quick = build_plan(quick=True)
    assert quick.seeds == [0, 1] and all(r.steps == ENVS[r.env].quick_steps for r in quick.runs)
    with pytest.raises(ValueError, match="unknown env"):
        build_plan(envs=["nope"])


def test_cli_registers_bench_paper() -> None:
    args = build_parser().parse_args(["bench", "paper", "--quick", "--jobs", "1", "--report-only"])
    assert args.quick and args.jobs == 1 and args.report_only and callable(args.func)
    assert args.executor == "local" and args.ray_address is None
    args = build_parser().parse_args(["bench", "paper", "--executor", "ray", "--ray-address", "head:6379"])
    assert args.executor == "ray" and args.ray_address == "head:6379" and args.jobs is None
    args = build_parser().parse_args(["bench", "plans", "--executor", "ray"])
    assert args.executor == "ray" and args.ray_address is None
    with pytest.raises(SystemExit, match="needs --executor ray"):
        args = build_parser().parse_args(["bench", "paper", "--ray-address", "x:1", "--report-only"])
        args.func(args)


def test_sac_and_ppo_sit_beside_the_registry_algorithms() -> None:
    assert PAPER_ALGOS[:6] == ("adaptiveh", "td3", "ddpg", "sac", "ppo", "rkhs")
    assert set(ALGOS) <= set(PAPER_ALGOS)
    with pytest.raises(ValueError, match="unknown algo"):
        build_plan(algos=["a2c"])
