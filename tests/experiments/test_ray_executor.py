"""The Ray executor runs the paper bench's quick plan on a local 2-CPU Ray instance (loopback only) and
makes the same run files as the local executor; either executor's files make a rerun skip those runs.

The instance is a ``ray start --head --block`` child of this test (its own process group, ended by its
id at teardown); the bench connects to it by address, as it would to a cluster (2-4 minutes).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

# Ray on loopback only: a single-node instance bound to 127.0.0.1, no usage report, no draining wait.
# Ray reads these when it is imported, so they are set before (in this process: the bench's driver).
RAY_ENV = {
    "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",  # despite the name: node IP = 127.0.0.1 on Linux too
    "RAY_USAGE_STATS_ENABLED": "0",
    "RAY_GRACEFUL_SHUTDOWN_DRAIN_TIMEOUT_S": "0",
    "RAY_AUTH_MODE": "disabled",  # head and driver agree whatever ~/.ray holds (loopback only anyway)
}
os.environ.update(RAY_ENV)

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install -e '.[ray]'): no Ray executor")
pytest.importorskip("stable_baselines3")

from paper_tiny import STEPS, TINY  # noqa: E402

from experiments.paper import main_paper  # noqa: E402

# Set-up runs the 48-run tiny plan twice (locally, unless the paper-bench tests ran it, and on Ray).
# Marked ``ray``: out of the default run (its set-up alone took 3 minutes on a busy 2-core machine);
# ``.ci/run`` runs it after the default run (``scripts/test.sh -m ray``).
pytestmark = [pytest.mark.timeout(1800), pytest.mark.ray]
# What a run's record holds that depends on the machine or the moment, not on the run.
VARIABLE = {"wall_s", "steps_per_s", "peak_rss_mb", "finished_at", "executor", "host"}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _descendants(pid: int) -> set[int]:
    """The processes below ``pid`` (from /proc), so that teardown ends exactly what the test started."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    out, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            if child not in out:
                out.add(child)
                todo.append(child)
    return out


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.fixture(scope="module")
def ray_address(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    from ray._private import ray_constants, services

    if ray_constants.ENABLE_RAY_CLUSTER:  # Ray was imported before this module set RAY_ENV
        ray_constants.ENABLE_RAY_CLUSTER = False
    # Else the driver would rewrite 127.0.0.1 to this machine's network address and never reach the head.
    assert services.get_node_ip_address() == "127.0.0.1"
    port = _free_port()
    temp = Path(f"/tmp/ray-{os.getpid()}")  # Ray's socket paths must stay short: not under pytest's tmp
    log = tmp_path_factory.mktemp("ray") / "ray_start.log"
    ray_bin = str(Path(sys.executable).with_name("ray"))
    cmd = [ray_bin, "start", "--head", "--block", "--num-cpus", "2", "--node-ip-address", "127.0.0.1",
           "--port", str(port), "--include-dashboard", "false", "--disable-usage-stats",
           "--object-store-memory", str(100 * 2**20), "--temp-dir", str(temp)]  # fmt: skip
    with log.open("w") as sink:
        head = subprocess.Popen(cmd, stdout=sink, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 180
        while "Ray runtime started" not in log.read_text():
            if head.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"ray start did not come up:\n{log.read_text()[-3000:]}")
            time.sleep(0.5)
        yield f"127.0.0.1:{port}"
    finally:
        started = _descendants(head.pid) | {head.pid}
        if ray.is_initialized():
            ray.shutdown()
        os.killpg(head.pid, signal.SIGTERM)  # the head's own group: ray start and what it spawned
        try:
            head.wait(timeout=60)
        except subprocess.TimeoutExpired:
            head.kill()
        time.sleep(1)
        for pid in started | _descendants(head.pid):
            if _alive(pid):
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture(scope="module")
def ray_run(ray_address: str, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("paper_ray")
    summary = main_paper(
        quick=True,
        out=out,
        jobs=None,
        seeds=2,
        steps=STEPS,
        overrides=TINY,
        progress=False,
        executor="ray",
        ray_address=ray_address,
    )
    return out, summary


def _runs(out: Path) -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in (out / "runs").glob("*.json")}


def test_ray_runs_the_quick_plan_as_the_local_executor_does(
    ray_run: tuple[Path, dict], tiny_run: tuple[Path, dict]
) -> None:
    out, summary = ray_run
    assert not ray.is_initialized()  # the bench connected for its runs and disconnected after
    assert summary["failed_runs"] == [] and summary["missing_runs"] == []
    assert summary["last_invocation"]["ran"] == summary["plan"]["runs_total"] == 48
    local_out, local_summary = tiny_run
    by_ray, by_local = _runs(out), _runs(local_out)
    assert set(by_ray) == set(by_local) and len(by_ray) == 48  # the same run ids
    for name, remote in by_ray.items():
        local = by_local[name]
        assert set(remote) == set(local), name  # the same record structure
        assert remote["executor"] == "ray" and local["executor"] == "local"
        assert remote["code"]["commit"] == local["code"]["commit"]  # the shipped tree is this one
        assert remote["wall_s"] > 0 and 20 < remote["peak_rss_mb"] < 8000
        # the same seed, settings and budget; runs are deterministic, so the same episodes as well
        for key in set(local) - VARIABLE:
            assert remote[key] == local[key], (name, key)
    assert summary["verdicts"] == local_summary["verdicts"]
    assert {a: c["runs"] for a, c in summary["cost"].items()} == {a: 8 for a in summary["plan"]["algos"]}


def test_reruns_skip_finished_runs_whichever_executor_made_them(
    ray_run: tuple[Path, dict], tiny_run: tuple[Path, dict], ray_address: str, tmp_path: Path
) -> None:
    ray_out, _ = ray_run
    kw = {"quick": True, "seeds": 2, "steps": STEPS, "overrides": TINY, "progress": False}
    # The local executor over the Ray-made files: nothing to do.
    again = main_paper(out=ray_out, jobs=2, **kw)
    assert again["last_invocation"] == {"skipped": 48, "ran": 0, "failed": 0}
    # The Ray executor over local files with two removed: only those two run.
    mixed = tmp_path / "mixed"
    shutil.copytree(tiny_run[0] / "runs", mixed / "runs")
    gone = [f"cartpole_fast__sac__s1__{STEPS}", f"reach_slow__ppo__s0__{STEPS}"]
    for name in gone:
        (mixed / "runs" / f"{name}.json").unlink()
    stamps = {p.name: p.stat().st_mtime_ns for p in (mixed / "runs").glob("*.json")}
    rerun = main_paper(out=mixed, jobs=None, executor="ray", ray_address=ray_address, **kw)
    assert rerun["last_invocation"] == {"skipped": 46, "ran": 2, "failed": 0}
    assert rerun["missing_runs"] == []
    kept = {p.name: p.stat().st_mtime_ns for p in (mixed / "runs").glob("*.json") if p.name in stamps}
    assert kept == stamps  # the local executor's files untouched
    for name in gone:
        assert json.loads((mixed / "runs" / f"{name}.json").read_text())["executor"] == "ray"


def test_cli_runs_the_ray_executor_against_an_address(ray_run: tuple[Path, dict], ray_address: str) -> None:
    """``adaptiveh bench paper --quick --executor ray --ray-address ADDR``: the one unfinished run (an RKHS
    run: its config is the same with and without the tests' overrides) goes to the cluster; the rest
    is skipped; the report prints each method's cost."""
    out, _ = ray_run
    name = f"cartpole_slow__rkhs__s0__{STEPS}"
    before = json.loads((out / "runs" / f"{name}.json").read_text())
    (out / "runs" / f"{name}.json").unlink()
    cli = str(Path(sys.executable).with_name("adaptiveh"))
    cmd = [cli, "bench", "paper", "--quick", "--steps", str(STEPS), "--out", str(out),
           "--executor", "ray", "--ray-address", ray_address, "--no-progress"]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env={**os.environ, **RAY_ENV})
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Cost per method" in proc.stdout and "missing runs: 0" in proc.stdout
    assert "SAC" in proc.stdout and "PPO" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["last_invocation"] == {"skipped": 47, "ran": 1, "failed": 0}
    after = json.loads((out / "runs" / f"{name}.json").read_text())
    assert after["executor"] == "ray" and after["episodes"] == before["episodes"]
