"""Under pytest, however started, our packages are the repository's and not the test folders of the same
name (``tests/sim``, ``tests/tasks``, ...), which would load as empty namespace packages and skip each
package's ``__init__`` (``tasks`` registers the environments there)."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = sorted(p.parent.name for p in ROOT.glob("*/__init__.py"))


@pytest.mark.parametrize("name", PACKAGES)
def test_each_package_is_the_repositorys(name: str) -> None:
    module = importlib.import_module(name)
    assert module.__file__ is not None, f"{name} loaded as a namespace package from {list(module.__path__)}"
    assert Path(module.__file__).resolve() == ROOT / name / "__init__.py"
