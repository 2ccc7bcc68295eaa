"""The plans bench on a tiny budget: runs in plan mode, the front/point/latency/drift report, figures,
TD3/DDPG reference points, resumability and a partial report that names its missing runs (< 60 s)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest

from deploy.commands import bench
from experiments.plans import SETTINGS, build_plans_plan, env_kwargs, main_plans
from experiments.plans_report import front_gap
from experiments.report import finite_leaves

FIGURES = ("front.png", "latency.png", "h_drift.png")
STEPS = 150
SHAPE = {"front_h": (1, 5), "thresholds": (0.8,), "latencies": (0, 2)}
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


@pytest.fixture(scope="module")  # 20 runs of 150 steps, one process each
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
    # 2 settings x (2 fixed H + 2 AdaptiveH) x 2 seeds, + latency on cartpole_fast: H=10 at L 0 and
    # H=1, H=10, AdaptiveH 0.8 at L 2, 2 seeds
    assert len(files) == summary["plan"]["runs_total"] == 16 + 8
    for path in files:
        run = json.loads(path.read_text())
        assert run["config"]["execution"] == "plan" and run["global_step"] == STEPS
        assert run["plan_channel"]["latency_steps"] == run["config"]["latency_steps"]
        assert run["segments"]["H"] and sum(run["segments"]["H"]) <= STEPS
        if run["algo"] == "rkhs":
            assert max(run["segments"]["H"]) <= run["config"]["fixed_h"]
            assert "retreat" not in run["segments"]["reason"]
        else:
            assert run["config"]["retreat"] in ("plan", "local")
    h1 = json.loads((out / "runs" / f"cartpole_slow__rkhs-h1__s0__{STEPS}.json").read_text())
    assert set(h1["segments"]["H"]) == {1} and h1["plan_channel"]["dropped_planned"] == 0


def test_summary_has_front_points_latency_drift_and_baselines(tiny: tuple[Path, dict]) -> None:
    out, summary = tiny
    on_disk = json.loads((out / "summary.json").read_text())
    assert finite_leaves(on_disk) == []
    assert set(on_disk["settings"]) == set(SETTING_KEYS)
    for s in on_disk["settings"].values():
        assert [f["H"] for f in s["front"]] == [1, 5]
        assert s["front"][0]["replans_per_100"]["mean"] == pytest.approx(100.0)
        assert set(s["points"]) == {"adaptiveh-plan0.8", "adaptiveh-local"}
        for p in s["points"].values():
            assert (
                p["n"] == 2
                and p["final_return"]["lo"] <= p["final_return"]["mean"] <= p["final_return"]["hi"]
            )
            v = p["vs_front"]
            assert v["lo"] <= v["diff"] <= v["hi"] or math.isclose(v["lo"], v["hi"])
            assert v["outcome"] in ("better", "tie", "worse") and v["position"]
    base = on_disk["settings"]["cartpole_fast"]["baselines"]
    assert base["td3"]["seeds"] == [0] and base["td3"]["final_return"]["mean"] == 100.0
    assert on_disk["settings"]["cartpole_slow"]["baselines"] == {}
    lat = on_disk["latency"]
    assert list(lat) == ["cartpole_fast"]
    for c in lat["cartpole_fast"]["curves"].values():
        assert [p["latency_steps"] for p in c["points"]] == [0, 2] and all(p["n"] == 2 for p in c["points"])
    drift = on_disk["h_drift"]["cartpole_slow-cartpole_fast"]["methods"]["adaptiveh-plan0.8"]
    assert drift["slow"]["n"] == 2 and "mean_H" in drift["slow_minus_fast"]
    for claim in ("above_fixed_h_front", "latency_adaptiveh_vs_fixed", "h_narrows_when_faster"):
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


def test_figures_are_real_pngs(tiny: tuple[Path, dict]) -> None:
    import matplotlib.image as mpimg

    out, summary = tiny
    assert sorted(summary["figures"]) == sorted(FIGURES)
    for name in FIGURES:
        img = mpimg.imread(out / name)
        assert img.ndim == 3 and img.shape[0] > 200 and float(np.std(img)) > 0.01


def test_finished_runs_are_never_recomputed_and_the_cli_reports_a_partial_plan(
    tiny: tuple[Path, dict], capsys: pytest.CaptureFixture
) -> None:
    out, _ = tiny
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


def test_plan_order_and_shape() -> None:
    plan = build_plans_plan()
    assert len(plan.runs) == len(set(r.name for r in plan.runs)) == 5 * 5 * 10 + 5 * 2 * 3 * 3
    order = [(r.seed, bool(r.latency)) for r in plan.runs]
    # seed by seed; each seed's latency runs right after the next seed's front and points
    blocks = [k for i, k in enumerate(order) if i == 0 or order[i - 1] != k]
    assert blocks == [(0, False), (1, False), (0, True), (2, False), (1, True), (3, False), (2, True),
                      (4, False), (3, True), (4, True)]  # fmt: skip
    first = [r.env for r in plan.runs[:50]]
    assert first.index("reach_slow") > max(i for i, e in enumerate(first) if not e.startswith("reach"))
    assert {r.steps for r in plan.runs if r.env.startswith("reach")} == {10_000}
    assert {r.env_kwargs["motion"] for r in plan.runs if r.env == "reach_fast"} == {"fast"}
    with pytest.raises(ValueError, match="unknown setting"):
        build_plans_plan(settings=["nope"])
