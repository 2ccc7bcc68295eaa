"""``adaptiveh up --check``: validates a config and names missing drivers without starting anything."""

import importlib.util
import subprocess
import sys

import pytest


def _check(path: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "deploy.cli", "up", path, "--check"],
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.skipif(
    importlib.util.find_spec("pylibfranka") is not None, reason="pylibfranka is installed here"
)
def test_franka_check_names_missing_drivers():
    out = _check("configs/franka_realsense.yaml")
    assert out.returncode == 1
    assert "MISSING driver pylibfranka" in out.stdout
    assert ("MISSING driver pyrealsense2" in out.stdout) == (importlib.util.find_spec("pyrealsense2") is None)
    assert "nothing was started and nothing moved" in out.stdout


def test_sim_check_passes_and_bad_config_is_named(tmp_path):
    assert _check("configs/sim.yaml").returncode == 0
    bad = tmp_path / "bad.yaml"
    bad.write_text(open("configs/sim.yaml").read().replace("algo: adaptiveh", "algo: ppo"))
    out = _check(str(bad))
    assert out.returncode == 1 and "learner" in out.stdout and "ppo" in out.stdout


def test_sim_camera_on_a_real_arm_is_refused(tmp_path):
    """The sim camera renders the world the pybullet mock publishes; on a Franka it would see nothing."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(open("configs/franka_realsense.yaml").read().replace("camera: realsense", "camera: sim"))
    out = _check(str(bad))
    assert out.returncode == 1 and "only the pybullet backend publishes" in out.stdout
