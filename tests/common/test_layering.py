"""Imports point down (docs/departures.md, "Layering"): each top-level folder imports only the folders
below it; the libraries (learner, robot_io, vision) import neither ``sim`` nor ``deploy`` (their
simulation backends are handed their world by ``tasks.sim_world``)."""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterable
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


def _module_graph(root: Path, packages: Iterable[str] = ALLOWED) -> dict[str, set[str]]:
    """Which of our modules each of our modules imports, at any depth (``from a import b`` counts as
    ``a.b`` when that is a module)."""
    files = {}
    for pkg in packages:
        for path in (root / pkg).rglob("*.py"):
            name = ".".join(path.relative_to(root).with_suffix("").parts)
            files[name.removesuffix(".__init__")] = path
    graph = {}
    for name, path in files.items():
        out = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                out |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                out |= {
                    f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in files else node.module
                    for a in node.names
                }
        graph[name] = (out & files.keys()) - {name}
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str]:
    """One import cycle (its modules in order, the first repeated at the end), or [] when there is none."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str]:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        state[node] = 2
        path.pop()
        return []

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return []


def test_no_import_cycle_between_modules():
    """Imports go one way inside a folder too (the plans experiment once looped plans -> plans_report ->
    plans); lazy imports count."""
    cycle = _cycle(_module_graph(ROOT))
    assert not cycle, "import cycle: " + " -> ".join(cycle)


def test_the_check_sees_an_import_cycle(tmp_path):
    """A lazy import back to the importer, as ``experiments.plans`` had, is a cycle."""
    (tmp_path / "experiments").mkdir()
    (tmp_path / "experiments" / "plans.py").write_text("def main():\n    from experiments.report import r\n")
    (tmp_path / "experiments" / "report.py").write_text("from experiments import plans\n")
    assert _cycle(_module_graph(tmp_path, ["experiments"])) == [
        "experiments.plans",
        "experiments.report",
        "experiments.plans",
    ]
    (tmp_path / "experiments" / "plans.py").write_text("X = 1\n")
    assert _cycle(_module_graph(tmp_path, ["experiments"])) == []


# deploy's processes (each a node of the bus, and the supervisor that starts them) and its command line:
# what two of them share lives in a module beside them, never in one of them.
NODES = (
    "deploy.actor_node",
    "deploy.learner_node",
    "deploy.robot_io_node",
    "deploy.vision_node",
    "deploy.stack",
)
ENTRY_POINTS = ("deploy.cli", "deploy.commands")


def _cross_node_imports(graph: dict[str, set[str]]) -> list[str]:
    wrong = []
    for node in NODES:
        for target in sorted(graph.get(node, ())):
            if target != node and (target in NODES or target.startswith(ENTRY_POINTS)):
                wrong.append(f"{node} imports {target}")
    return wrong


def test_no_node_imports_another_node():
    wrong = _cross_node_imports(_module_graph(ROOT, ["deploy"]))
    assert not wrong, "a node importing another node or the CLI:\n" + "\n".join(wrong)


def test_the_check_sees_a_node_importing_another(tmp_path):
    (tmp_path / "deploy" / "commands").mkdir(parents=True)
    (tmp_path / "deploy" / "learner_node.py").write_text("X = 1\n")
    (tmp_path / "deploy" / "commands" / "__init__.py").write_text("Y = 1\n")
    (tmp_path / "deploy" / "actor_node.py").write_text("from deploy.learner_node import X\n")
    (tmp_path / "deploy" / "stack.py").write_text("def f():\n    from deploy.commands import Y\n")
    assert _cross_node_imports(_module_graph(tmp_path, ["deploy"])) == [
        "deploy.actor_node imports deploy.learner_node",
        "deploy.stack imports deploy.commands",
    ]


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
