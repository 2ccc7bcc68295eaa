"""Imports point down (README "Layering"): each top-level folder imports only the folders below it; the
libraries (learner, robot_io, vision) import neither ``sim`` nor ``deploy`` (their simulation backends
are handed their world by ``tasks.sim_world``)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# What each folder may import (besides itself).
ALLOWED = {
    "common": set(),
    "sim": {"common"},
    "learner": {"common"},
    "robot_io": {"common"},
    "vision": {"common"},
    "tasks": {"common", "sim", "learner", "robot_io", "vision"},
    "bus": {"common"},
    "monitor": {"common", "bus", "robot_io", "vision"},
    "experiments": {"common", "sim", "learner", "robot_io", "vision", "tasks"},
    "deploy": {"common", "sim", "learner", "robot_io", "vision", "tasks", "bus", "monitor", "experiments"},
}


def _imports(path: Path) -> set[str]:
    """The top-level packages of ours that ``path`` imports, at any depth (lazy imports count)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out & set(ALLOWED)


def test_every_import_points_down():
    wrong = []
    for pkg, allowed in ALLOWED.items():
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            wrong += [f"{rel} imports {target}" for target in _imports(path) - {pkg} - allowed]
    assert not wrong, "imports pointing up or across:\n" + "\n".join(wrong)


def test_the_check_sees_an_upward_import(tmp_path, monkeypatch):
    """The walk finds lazy imports inside functions (the form an upward import usually takes)."""
    path = tmp_path / "mod.py"
    path.write_text("def f():\n    from deploy.config import StackConfig\n    import bus.messages\n")
    assert _imports(path) == {"deploy", "bus"}


def test_robot_io_for_a_real_arm_loads_no_simulator():
    """Loading the Franka config and robot-io's node pulls in neither PyBullet, gymnasium nor ``sim``."""
    code = (
        "import sys\n"
        "from deploy.config import load_stack_config\n"
        "from deploy.robot_io_node import RobotIONode\n"
        "load_stack_config('configs/franka_realsense.yaml')\n"
        "print(sorted(m for m in ('pybullet', 'gymnasium', 'sim') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]"
