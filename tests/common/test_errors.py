"""Every error this code raises on purpose derives from the project's root, ``common.errors.AdaptiveHError``
(``except AdaptiveHError`` catches them all); each keeps the built-in base a caller may already catch."""

from __future__ import annotations

import ast
import builtins
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = (
    "common",
    "sim",
    "learner",
    "robot_io",
    "vision",
    "tasks",
    "bus",
    "monitor",
    "experiments",
    "deploy",
)
BUILTIN_ERRORS = {
    name for name, obj in vars(builtins).items() if isinstance(obj, type) and issubclass(obj, BaseException)
}


def _base_name(node: ast.expr) -> str:
    return node.attr if isinstance(node, ast.Attribute) else getattr(node, "id", "")


def _exception_classes(root: Path) -> dict[str, tuple[str, list[str]]]:
    """Our classes that derive from an exception: name -> (file, base names)."""
    classes = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.ClassDef):
                    classes[node.name] = (
                        path.relative_to(root).as_posix(),
                        [_base_name(b) for b in node.bases],
                    )
    errors: dict[str, tuple[str, list[str]]] = {}
    changed = True
    while changed:  # a class is an exception when one of its bases is a built-in one or one of ours
        changed = False
        for name, (where, bases) in classes.items():
            if name not in errors and any(b in BUILTIN_ERRORS or b in errors for b in bases):
                errors[name] = (where, bases)
                changed = True
    return errors


def _outside_the_root(errors: dict[str, tuple[str, list[str]]]) -> list[str]:
    def rooted(name: str, seen: frozenset = frozenset()) -> bool:
        if name == "AdaptiveHError":
            return True
        bases = errors.get(name, ("", []))[1]
        return any(b not in seen and rooted(b, seen | {name}) for b in bases)

    return [f"{where}: {name}" for name, (where, _) in sorted(errors.items()) if not rooted(name)]


def test_every_error_of_ours_derives_from_the_root():
    errors = _exception_classes(ROOT)
    assert {"MessageError", "SnapshotError", "CameraError", "HandoffMismatch"} <= errors.keys()
    wrong = _outside_the_root(errors)
    assert not wrong, "errors not under common.errors.AdaptiveHError:\n" + "\n".join(wrong)


def test_the_check_sees_an_error_outside_the_root(tmp_path):
    (tmp_path / "common").mkdir()
    (tmp_path / "common" / "errors.py").write_text("class AdaptiveHError(Exception):\n    pass\n")
    (tmp_path / "bus").mkdir()
    (tmp_path / "bus" / "m.py").write_text(
        "class Good(AdaptiveHError, ValueError):\n    pass\n"
        "class Child(Good):\n    pass\n"
        "class Stray(RuntimeError):\n    pass\n"
    )
    assert _outside_the_root(_exception_classes(tmp_path)) == ["bus/m.py: Stray"]
