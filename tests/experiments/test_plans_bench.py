"""The plans bench on a tiny budget: runs in plan mode (TD3 too), the front/point/latency/drift report,
figures, the baselines in plan mode and their closed-loop reference points, resumability and a partial
report that names its missing runs (< 90 s)."""

from __future__ import annotations

import argparse
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from deploy.commands import bench
from experiments.plans import (
    DEFAULT_ONLY,
    SETTINGS,
    baseline_of,
    build_plans_plan,
    env_kwargs,
    method_config,
    method_label,
)
from experiments.plans_bench import main_plans
from experiments.plans_report import best_fixed_h_per_seed, front_gap, front_gap_if_best, run_numbers
from experiments.report import finite_leaves

FIGURES = ("front.png", "latency.png", "h_drift.png")
STEPS = 150
# TD3 re-planning every 5 steps on cartpole_fast (a BASELINE_SETTINGS member), seeds 0 and 1.
SHAPE = {
    "front_h": (1, 5),
    "thresholds": (0.8,),
    "kernel_scales": (0.15,),
    "latencies": (0, 2),
    "baseline_methods": ("td3",),
    "baseline_h": (5,),
}
SETTING_KEYS = ["cartpole_slow", "cartpole_fast"]


def _fake_paper(root: Path) -> Path:
    """A paper-bench result folder with TD3 runs of cartpole_fast at this budget (seed 1: another world)."""
    (root / "runs").mkdir(parents=True)
    for seed, ret in ((0, 100.0), (1, 120.0)):
        kwargs = env_kwargs(SETTINGS["cartpole_fast"], seed)
        if seed == 1:
            kwargs = {**kwargs, "preset": "slow"}  # not the same world: must be left out
        run = {"env_kwargs": kwargs, "metrics": {"final_return": ret, "return_mean": ret / 2}}
        (root / "runs" / f"cartpole_fast__td3__s{seed}__{STEPS}.json").write_text(json.dumps(run))
    return root


@pytest.fixture(scope="module")  # 44 runs of 150 steps, one process each
def tiny(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("plans")
    paper = _fake_paper(tmp_path_factory.mktemp("paper"))
    summary = main_plans(
        False, out, 2, seeds=2, steps=STEPS, settings=SETTING_KEYS, progress=False, paper_dir=paper, **SHAPE
    )
    return out, summary


def test_every_run_is_in_plan_mode_with_its_own_file(tiny: tuple[Path, dict]) -> None:
    out, summary = tiny
    assert summary["failed_runs"] == [] and summary["missing_runs"] == [] and summary["stale_runs"] == []
    files = sorted((out / "runs").glob("*.json"))
    # 2 settings x (2 fixed H + 6 AdaptiveH points) x 2 seeds, + latency on cartpole_fast: H=10 at L 0
    # and H=1, H=10, AdaptiveH 0.8, the default at L 2, 2 seeds, + TD3 at H = 5 on cartpole_fast, 2 seeds
    assert len(files) == summary["plan"]["runs_total"] == 32 + 10 + 2
    for path in files:
        run = json.loads(path.read_text())
        assert run["global_step"] == STEPS and run["segments"]["H"] and sum(run["segments"]["H"]) <= STEPS
        if run["algo"] == "td3":  # SB3's loop: no learner latency, an episode's end drops the plan's rest
            assert run["config"] == {"plan_h": 5} and run["env"] == "cartpole_fast"
            assert max(run["segments"]["H"]) == 5
            assert set(run["segments"]["reason"]) <= {"h_max", "episode_end"}
            assert run["plan_channel"]["latency_steps"] == 0 and run["plan_channel"]["dropped_planned"] >= 0
            continue
        assert run["config"]["execution"] == "plan"
        assert run["plan_channel"]["latency_steps"] == run["config"]["latency_steps"]
        if run["algo"] == "rkhs":
            assert max(run["segments"]["H"]) <= run["config"]["fixed_h"]
            assert "retreat" not in run["segments"]["reason"]
        else:
            assert run["config"].get("retreat", "plan") in ("plan", "local")  # unset: plan mode's own
    h1 = json.loads((out / "runs" / f"cartpole_slow__rkhs-h1__s0__{STEPS}.json").read_text())
    assert set(h1["segments"]["H"]) == {1} and h1["plan_channel"]["dropped_planned"] == 0


def test_summary_has_front_points_latency_drift_and_baselines(tiny: tuple[Path, dict]) -> None:
    out, summary = tiny
    on_disk = json.loads((out / "summary.json").read_text())
    assert finite_leaves(on_disk) == []
    assert set(on_disk["settings"]) == set(SETTING_KEYS)
    assert set(on_disk["machines"]) == set(SETTING_KEYS)  # every setting's runs from this one machine
    assert all(len(by_cpu) == 1 and "unrecorded" not in by_cpu for by_cpu in on_disk["machines"].values())
    for s in on_disk["settings"].values():
        assert [f["H"] for f in s["front"]] == [1, 5]
        assert s["front"][0]["replans_per_100"]["mean"] == pytest.approx(100.0)
        assert set(s["points"]) == {
            "adaptiveh-plan0.8",
            "adaptiveh-k0.15",
            "adaptiveh-local",
            "adaptiveh-learned",
            "adaptiveh-default",
            "adaptiveh-corrected",
        }
        for p in s["points"].values():
            assert (
                p["n"] == 2
                and p["final_return"]["lo"] <= p["final_return"]["mean"] <= p["final_return"]["hi"]
            )
            v = p["vs_front"]
            assert v["lo"] <= v["diff"] <= v["hi"] or math.isclose(v["lo"], v["hi"])
            assert v["outcome"] in ("better", "tie", "worse") and v["position"]
            paired = p["vs_front_paired"]  # each seed against its own front
            assert set(paired["per_seed"]) == {"0", "1"} and paired["lo"] <= paired["diff"] <= paired["hi"]
            assert p["vs_H1_paired"]["n_a"] == 2 and p["vs_H1_paired"]["fewer_replans"] >= 1
            assert set(p["minus_H5_per_seed"]) == {"0", "1"}
            best = p["vs_front_if_best_fixed_H"]  # the best fixed H on each seed, at the point's rates
            assert len(best["returns"]) == 2 and best["lo"] <= best["diff"] <= best["hi"]
    base = on_disk["settings"]["cartpole_fast"]["baselines"]
    assert base["td3"]["seeds"] == [0] and base["td3"]["final_return"]["mean"] == 100.0
    assert on_disk["settings"]["cartpole_slow"]["baselines"] == {}
    assert on_disk["settings"]["cartpole_slow"]["plan_baselines"] == {}  # not a baseline setting
    td3 = on_disk["settings"]["cartpole_fast"]["plan_baselines"]["td3-h5"]
    assert (td3["n"], td3["H"], td3["algo"], td3["planned_seeds"]) == (2, 5, "td3", [0, 1])
    assert 20.0 <= td3["replans_per_100"]["mean"] <= 100.0 and td3["H_mean"]["mean"] <= 5
    assert td3["vs_front"]["outcome"] in ("better", "tie", "worse")
    assert td3["minus_closed_loop"]["n_b"] == 1  # against the paper bench's closed-loop TD3 (seed 0)
    for p in on_disk["settings"]["cartpole_fast"]["points"].values():
        assert p["vs_plan_baselines"]["td3-h5"]["n_b"] == 2
    assert set(on_disk["verdicts"]["above_plan_baselines"]["comparisons"]) == {
        "cartpole_fast:adaptiveh-plan0.8:td3-h5",
        "cartpole_fast:adaptiveh-k0.15:td3-h5",
        "cartpole_fast:adaptiveh-local:td3-h5",
        "cartpole_fast:adaptiveh-learned:td3-h5",
        "cartpole_fast:adaptiveh-default:td3-h5",
        "cartpole_fast:adaptiveh-corrected:td3-h5",
    }
    lat = on_disk["latency"]
    assert list(lat) == ["cartpole_fast"]
    for c in lat["cartpole_fast"]["curves"].values():
        assert [p["latency_steps"] for p in c["points"]] == [0, 2] and all(p["n"] == 2 for p in c["points"])
    drift = on_disk["h_drift"]["cartpole_slow-cartpole_fast"]["methods"]["adaptiveh-plan0.8"]
    assert drift["slow"]["n"] == 2 and "mean_H" in drift["slow_minus_fast"]
    rivals = {f"L{lat}:rkhs-h{h}" for lat in (0, 2) for h in (1, 10)}
    assert set(lat["cartpole_fast"]["default_minus_fixed"]) == rivals
    for claim, key in (
        ("latency_adaptiveh_vs_fixed", "adaptiveh_minus_fixed"),
        ("latency_default_vs_fixed", "default_minus_fixed"),
    ):  # each verdict reads its own method's comparisons
        own = {f"cartpole_fast:{c}": d for c, d in lat["cartpole_fast"][key].items()}
        assert on_disk["verdicts"][claim]["comparisons"] == own, claim
    for claim in (
        "above_fixed_h_front",
        "latency_adaptiveh_vs_fixed",
        "latency_default_vs_fixed",
        "h_narrows_when_faster",
    ):
        assert on_disk["verdicts"][claim]["verdict"].split(" (")[0] in (
            "confirmed",
            "partly confirmed",
            "not confirmed",
        )
    per_run = on_disk["per_run"]
    assert set(per_run) == {p.stem for p in (out / "runs").glob("*.json")}
    assert all(r["replans_per_100"] > 0 and r["dropped_planned"] is not None for r in per_run.values())
    table = (out / "summary.md").read_text()
    assert "above the front" in table or "below the front" in table or "on the front" in table
    assert "nan" not in table and "TD3 (closed loop" in table
    assert "## Baselines in plan mode" in table and "| TD3, H = 5 (plan mode) |" in table


def test_figures_are_real_pngs(tiny: tuple[Path, dict]) -> None:
    import matplotlib.image as mpimg

    out, summary = tiny
    assert sorted(summary["figures"]) == sorted(FIGURES)
    for name in FIGURES:
        img = mpimg.imread(out / name)
        assert img.ndim == 3 and img.shape[0] > 200 and float(np.std(img)) > 0.01


def test_finished_runs_are_never_recomputed_and_the_cli_reports_a_partial_plan(
    tiny: tuple[Path, dict], tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    out = tmp_path / "plans"  # this test rewrites the summary and figures: a copy, the others read theirs
    shutil.copytree(tiny[0], out)
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.json")}
    again = main_plans(False, out, 2, seeds=2, steps=STEPS, settings=SETTING_KEYS, progress=False, **SHAPE)
    assert again["last_invocation"]["ran"] == 0 and again["last_invocation"]["skipped"] == len(stamps)
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.json")} == stamps
    # The full shape over the same folder: most runs missing, named, and every figure still drawn.
    parser = argparse.ArgumentParser()  # the bench command alone: other commands' imports stay out
    bench.register(parser.add_subparsers())
    args = parser.parse_args(
        [
            "bench",
            "plans",
            "--report-only",
            "--out",
            str(out),
            "--seeds",
            "2",
            "--steps",
            str(STEPS),
            "--settings",
            *SETTING_KEYS,
            "--no-progress",
        ]  # fmt: skip
    )
    assert args.func(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert f"cartpole_fast__rkhs-h50__s1__{STEPS}" in summary["missing_runs"]
    assert summary["settings"]["cartpole_fast"]["front"][-1]["n"] == 0
    assert f"cartpole_fast__sac-h10__s1__{STEPS}" in summary["missing_runs"]  # a missing baseline: n 0
    assert summary["settings"]["cartpole_fast"]["plan_baselines"]["sac-h10"]["n"] == 0
    assert finite_leaves(summary) == []
    assert "missing runs" in capsys.readouterr().out


def test_front_gap_interpolates_in_log_rate() -> None:
    front = [([100.0, 100.0], [0.0, 0.0]), ([10.0, 10.0], [10.0, 10.0])]
    # halfway in log rate between 10 and 100 -> front return 5; point return 8 -> +3
    gap = front_gap(front, ([math.sqrt(1000.0)] * 2, [8.0, 8.0]))
    assert gap["diff"] == pytest.approx(3.0) and not gap["extrapolated"]
    assert gap["lo"] == pytest.approx(3.0) and gap["hi"] == pytest.approx(3.0)
    low = front_gap(front, ([2.0, 2.0], [4.0, 4.0]))  # below the front's range: clamped to H's end
    assert low["extrapolated"] and low["diff"] == pytest.approx(-6.0)


def test_the_best_fixed_h_is_taken_per_seed_and_placed_at_the_points_rates() -> None:
    def group(h: int, rets: list[float]) -> dict:
        return {
            "H": h,
            "seeds": [0, 1],
            "per_seed": {"replans_per_100": [100.0 / h] * 2, "final_return": rets},
        }

    front = [group(1, [5.0, 1.0]), group(10, [2.0, 9.0])]
    pairs = [(f["per_seed"]["replans_per_100"], f["per_seed"]["final_return"]) for f in front]
    assert best_fixed_h_per_seed(front, [1, 0]) == [9.0, 5.0]
    assert best_fixed_h_per_seed(front, [0, 2]) is None  # seed 2 has no fixed-H run
    point = {
        "n": 2,
        "seeds": [0, 1],
        "per_seed": {"replans_per_100": [10.0, 10.0], "final_return": [0.0, 0.0]},
    }
    got = front_gap_if_best(front, pairs, point, seed=0)
    # at rate 10 the front's mean is (2 + 9) / 2; the best per seed is (5 + 9) / 2: +1.5
    assert got["returns"] == [5.0, 9.0] and got["diff"] == pytest.approx(1.5)
    assert got == {
        **front_gap(pairs, ([10.0, 10.0], [5.0, 9.0])),
        "outcome": got["outcome"],
        "returns": [5.0, 9.0],
    }


def test_plan_order_and_shape() -> None:
    plan = build_plans_plan()
    # front (6) + points (3 thresholds, 2 kernel scales, local, learned, the default, corrected) on 5
    # settings, the front, the default and corrected alone on the held-out one, the latency sweep (H = 1,
    # H = 10, 0.8, the default), and TD3/SAC at H = 10 on cartpole_fast and reach_slow, 3 seeds
    assert (
        len(plan.runs)
        == len(set(r.name for r in plan.runs))
        == 5 * 5 * 15 + 5 * 8 + 5 * 2 * 3 * 4 + 3 * 2 * 2
    )
    held_out = {r.method for r in plan.runs if r.env == "reach_erratic"}
    assert held_out == {f"rkhs-h{h}" for h in (1, 2, 5, 10, 20, 50)} | {
        "adaptiveh-default",
        "adaptiveh-corrected",
    }
    kind = {(False, False): "main", (True, False): "latency", (False, True): "baselines"}
    order = [(r.seed, kind[bool(r.latency), baseline_of(r.method) is not None]) for r in plan.runs]
    # seed by seed; each seed's latency runs, then its baselines, right after the next seed's front and points
    blocks = [k for i, k in enumerate(order) if i == 0 or order[i - 1] != k]
    assert blocks == [(0, "main"), (1, "main"), (0, "latency"), (0, "baselines"), (2, "main"), (1, "latency"),
                      (1, "baselines"), (3, "main"), (2, "latency"), (2, "baselines"), (4, "main"),
                      (3, "latency"), (4, "latency")]  # fmt: skip
    base = [r for r in plan.runs if baseline_of(r.method)]
    assert plan.baseline_methods == ["td3-h10", "sac-h10"] and plan.baseline_seeds == [0, 1, 2]
    assert {(r.env, r.algo, r.method) for r in base} == {
        (k, a, f"{a}-h10") for k in ("cartpole_fast", "reach_slow") for a in ("td3", "sac")
    }
    assert all(r.config == {"plan_h": 10} and r.latency == 0 for r in base)  # SB3 defaults, plan mode
    assert [r for r in plan.runs if r.algo in ("rkhs", "adaptiveh") and "latency_steps" not in r.config] == []
    first = [r.env for r in plan.runs[:50]]
    assert first.index("reach_slow") > max(i for i, e in enumerate(first) if not e.startswith("reach"))
    assert {r.steps for r in plan.runs if r.env.startswith("reach")} == {10_000}
    assert {r.env_kwargs["motion"] for r in plan.runs if r.env == "reach_fast"} == {"fast"}
    assert {r.env_kwargs["motion"] for r in plan.runs if r.env == "reach_erratic"} == {"erratic"}
    with pytest.raises(ValueError, match="unknown setting"):
        build_plans_plan(settings=["nope"])
    # Baselines only where their settings are planned, at most the experiment's seeds, none on request.
    small = build_plans_plan(seeds=2, settings=["cartpole_slow", "reach_slow"], baseline_h=(5, 20))
    assert small.baseline_settings == ["reach_slow"] and small.baseline_seeds == [0, 1]
    assert sorted(r.method for r in small.runs if baseline_of(r.method)) == sorted(
        ["td3-h5", "td3-h20", "sac-h5", "sac-h20"] * 2
    )
    assert not [r for r in build_plans_plan(baseline_seeds=0).runs if baseline_of(r.method)]
    with pytest.raises(ValueError, match="plan-mode baseline"):
        build_plans_plan(baseline_methods=("ppo",))
    with pytest.raises(ValueError, match="positive integer"):
        build_plans_plan(baseline_h=(0,))


def test_the_default_only_shape_runs_the_front_the_default_and_corrected_alone(tmp_path: Path) -> None:
    plan = build_plans_plan(seeds=10, **DEFAULT_ONLY)
    front = {f"rkhs-h{h}" for h in (1, 2, 5, 10, 20, 50)}
    assert {r.method for r in plan.runs} == front | {"adaptiveh-default", "adaptiveh-corrected"}
    assert len(plan.runs) == 6 * 8 * 10 and not [r for r in plan.runs if r.latency]
    parser = argparse.ArgumentParser()
    bench.register(parser.add_subparsers())
    for extra in ([], ["--out", str(tmp_path), "--latency-seeds", "2"]):  # results/plans keeps its points
        args = parser.parse_args(["bench", "plans", "--default-only", "--report-only", *extra])
        with pytest.raises(SystemExit, match="--default-only needs its own --out"):
            args.func(args)


def test_method_names_of_the_baselines_in_plan_mode() -> None:
    assert method_config("td3-h10") == ("td3", {"plan_h": 10})
    assert method_config("ddpg-h3") == ("ddpg", {"plan_h": 3})
    assert method_config("sac-h1") == ("sac", {"plan_h": 1})  # H = 1: SB3's closed loop
    assert method_config("rkhs-h5") == ("rkhs", {"execution": "plan", "fixed_h": 5})
    assert method_config("adaptiveh-k0.15") == (
        "adaptiveh",
        {"execution": "plan", "retreat": "plan", "plan_kernel_scale": 0.15, "plan_tolerance": "fixed"},
    )
    assert method_config("adaptiveh-plan0.8") == (
        "adaptiveh",
        {
            "execution": "plan",
            "retreat": "plan",
            "retreat_threshold": 0.8,
            "plan_tolerance": "fixed",
            "plan_kernel_scale": 1.0,
        },
    )
    assert method_config("adaptiveh-default") == ("adaptiveh", {"execution": "plan", "retreat": None})
    assert method_config("adaptiveh-corrected") == (
        "adaptiveh",
        {"execution": "plan", "retreat": None, "plan_model": "corrected"},
    )
    assert method_label("adaptiveh-k0.15") == "AdaptiveH, plan retreat, kernel x0.15"
    assert method_config("adaptiveh-learned") == (
        "adaptiveh",
        {"execution": "plan", "retreat": "plan", "plan_tolerance": "learned"},
    )
    assert method_label("td3-h10") == "TD3, H = 10" and method_label("sac-h1") == "SAC, H = 1 (closed loop)"
    assert baseline_of("ddpg-h20") == ("ddpg", 20) and baseline_of("rkhs-h20") is None
    for bad in ("td3-h0", "td3-h", "td3-hx", "td3-h1.5", "td3-h-3", "td3-h010", "sac-h 5", "rkhs-h0"):
        with pytest.raises(ValueError, match="positive integer"):
            method_config(bad)
    for bad in ("ppo-h5", "td3", "td3h5", "a2c-h5", "TD3-h5"):
        with pytest.raises(ValueError, match="unknown method"):
            method_config(bad)
        with pytest.raises(ValueError, match="unknown method"):
            method_label(bad)


def test_a_closed_loop_baseline_run_counts_as_h_1() -> None:
    """A baseline run at plan_h 1 (SB3's own loop) records no segments: one re-plan per step."""
    run = {
        "algo": "td3",
        "config": {"plan_h": 1},
        "global_step": 400,
        "segments": {"global_step": [], "H": [], "reason": []},
        "plan_channel": None,
        "metrics": {"final_return": 1.0, "return_mean": 0.5},
        "wall_s": 2.0,
    }
    n = run_numbers(run)
    assert (n["replans_per_100"], n["H_mean"], n["segments"], n["dropped_planned"]) == (100.0, 1.0, 400, 0)
    planned = {**run, "config": {"plan_h": 8}, "plan_channel": {"dropped_planned": 6, "latency_steps": 0}}
    planned["segments"] = {
        "global_step": [8, 16, 18],
        "H": [8, 8, 2],
        "reason": ["h_max", "h_max", "episode_end"],
    }
    n = run_numbers(planned)
    assert (n["replans_per_100"], n["H_mean"], n["dropped_planned"]) == (0.75, 6.0, 6)
