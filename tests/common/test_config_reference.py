"""The configuration reference (docs/reference/) says what the config models say now, lists every key of
every model a user writes in YAML, each with a description, and every config model of the project is on
its pages. After changing a model: ``adaptiveh config reference``."""

from __future__ import annotations

import argparse
import ast
import importlib
import re
import tomllib
import typing
from pathlib import Path

import pytest
from pydantic import BaseModel, Field

from deploy.commands.config import reference
from deploy.config import RecordingConfig, StackConfig, SupervisorConfig
from deploy.config_reference import COMMAND, REFERENCE_DIR, ROOT, description, render_pages, stale_pages
from experiments.training import TrainSpec
from learner.config import AGENT_CONFIGS


@pytest.fixture(scope="module")
def pages() -> dict[str, str]:
    return render_pages()


def _stale_message(stale: list[str]) -> str:
    return f"docs/reference/ is stale ({', '.join(stale)}): run `{COMMAND}` and commit the pages"


def test_the_committed_reference_is_what_the_models_say(pages):
    stale = stale_pages(pages)
    assert not stale, _stale_message(stale)


# -- every key, found by a walk of the models of its own (not the generator's) ----------------------


def _models(annotation: object) -> list[type[BaseModel]]:
    """Every model an annotation names, however deep (``Pose | None``, ``list[Pose]``, ``Annotated``)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in typing.get_args(annotation) for m in _models(arg)]


def _keys(model: type[BaseModel], prefix: str = "") -> list[str]:
    out = []
    for name, info in model.model_fields.items():
        key = f"{prefix}.{name}" if prefix else name
        out.append(key)
        for sub in _models(info.annotation):
            out += _keys(sub, key)
    return out


def _row(key: str) -> str:
    return f"| `{key}` |"


def _sections(pages: dict[str, str]) -> dict[str, str]:
    """Each ``## `` section of the pages (with its ``###`` subsections), by heading."""
    out = {}
    for text in pages.values():
        for part in re.split(r"^## ", text, flags=re.MULTILINE)[1:]:
            heading, _, body = part.partition("\n")
            out[heading] = body
    return out


def _missing(pages: dict[str, str]) -> list[str]:
    """The keys without a row: the stack's anywhere, each agent's in its algorithm's section, the task
    config's in its section."""
    text = "\n".join(pages.values())
    missing = [key for key in _keys(StackConfig) if _row(key) not in text]
    sections = _sections(pages)
    for algo, model in AGENT_CONFIGS.items():
        found = [body for heading, body in sections.items() if "learner.agent" in heading and algo in heading]
        body = found[0] if len(found) == 1 else ""
        missing += [f"{key} ({algo})" for key in _keys(model, "learner.agent") if _row(key) not in body]
    task = "".join(body for heading, body in sections.items() if "adaptiveh train" in heading)
    missing += [f"{key} (adaptiveh train)" for key in _keys(TrainSpec) if _row(key) not in task]
    return missing


def test_every_key_of_every_model_has_a_row(pages):
    assert len(_keys(StackConfig)) > 150  # the walk reaches the nested sections (robot.franka, zenoh.tls ...)
    assert not _missing(pages), f"keys missing from the reference: {_missing(pages)}; run `{COMMAND}`"
    committed = {name: (REFERENCE_DIR / name).read_text() for name in pages}
    assert not _missing(committed)


def test_the_key_check_sees_a_missing_row(pages):
    without = {
        name: "\n".join(
            line for line in text.splitlines() if not line.startswith(_row("robot.franka.dynamics"))
        )
        for name, text in pages.items()
    }
    assert _missing(without) == ["robot.franka.dynamics"]
    sac_gone = {name: text.replace("for sac", "for nothing") for name, text in pages.items()}
    assert _missing(sac_gone) == [f"{key} (sac)" for key in _keys(AGENT_CONFIGS["sac"], "learner.agent")]


# -- every key has a description -------------------------------------------------------------------


def undescribed(pages: dict[str, str]) -> list[str]:
    """The keys whose row has an empty description."""
    out = []
    for text in pages.values():
        for line in text.splitlines():
            if line.startswith("| `"):
                cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)]
                if not cells[5]:
                    out.append(cells[1].strip("`"))
    return out


def test_every_key_has_a_description(pages):
    assert not undescribed(pages), (
        f"keys without a description: {undescribed(pages)}; give each a `#` comment or a"
        f" Field(description=...), then run `{COMMAND}`"
    )


class _Supervisor(SupervisorConfig):
    grace_s: float = 1.0


class _Undescribed(StackConfig):
    supervisor: _Supervisor = _Supervisor()  # described: only grace_s is not


def test_the_description_check_sees_a_key_without_one(pages):
    assert undescribed(render_pages(stack=_Undescribed)) == ["supervisor.grace_s"]


# -- every config model of the project is in the reference -----------------------------------------

# The config models that no YAML file holds, so no page lists them; why not.
NOT_READ_FROM_YAML = {
    "experiments/plan.py:EnvSpec": "the paper bench's settings: a table in code",
    "sim/panda_scene.py:TargetMotion": "the target's motions: a config names a preset (robot.target_motion)",
    "sim/schedules.py:DriftConfig": "NS CartPole's and NS Pendulum's drift presets; env_kwargs name one",
}


def _packages(root: Path = ROOT) -> tuple[str, ...]:
    """The project's packages, as pyproject.toml lists them for setuptools."""
    found = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    return tuple(name.rstrip("*") for name in found["include"])


def config_models(root: Path = ROOT, packages: tuple[str, ...] | None = None) -> list[str]:
    """Every config model (a subclass of ``common.config.Section``, however indirect) declared in the
    project's packages, as ``path:Class``; read from the source, nothing imported."""
    classes = []
    for package in packages or _packages(root):
        for path in sorted((root / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ClassDef):
                    bases = {getattr(b, "id", None) or getattr(b, "attr", "") for b in node.bases}
                    classes.append((f"{path.relative_to(root).as_posix()}:{node.name}", node.name, bases))
    names = {"Section"}
    while True:
        more = {name for _, name, bases in classes if names & bases} - names
        if not more:
            break
        names |= more
    return sorted(where for where, _, bases in classes if names & bases)


def _on_a_page(where: str, pages: dict[str, str]) -> bool:
    path, name = where.split(":")
    return f"`{name}` (`{path}`)" in "\n".join(pages.values())


def unlisted(models: list[str], pages: dict[str, str]) -> list[str]:
    """The config models on no page of the reference (but those no YAML file holds)."""
    return [where for where in models if where not in NOT_READ_FROM_YAML and not _on_a_page(where, pages)]


def test_every_config_model_is_in_the_reference(pages):
    models = config_models()
    assert len(models) >= 30 and "deploy/config.py:StackConfig" in models
    assert not unlisted(models, pages), (
        f"config models in no page of the reference: {unlisted(models, pages)}; reach them from a stack"
        f" or task config (then run `{COMMAND}`), or say in NOT_READ_FROM_YAML why no YAML holds them"
    )
    for where in NOT_READ_FROM_YAML:  # each exception is a model, on no page
        assert where in models and not _on_a_page(where, pages), where


def test_the_models_no_yaml_holds_have_descriptions_too():
    for where in NOT_READ_FROM_YAML:
        path, name = where.split(":")
        model = getattr(importlib.import_module(path.removesuffix(".py").replace("/", ".")), name)
        assert all(description(model, key) for key in model.model_fields), where


def test_the_model_check_sees_a_new_model(pages, tmp_path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "extra.py").write_text(
        "from common.config import Section\n"
        "import common.config as cc\n\n"
        "class Extra(Section):\n    x: int = 1\n\n"
        "class MoreExtra(Extra):\n    y: int = 2\n\n"
        "class Qualified(cc.Section):\n    z: int = 3\n\n"
        "class NotAConfig:\n    pass\n"
    )
    models = config_models(tmp_path, ("pkg",))
    assert models == ["pkg/extra.py:Extra", "pkg/extra.py:MoreExtra", "pkg/extra.py:Qualified"]
    assert unlisted(models, pages) == models
    assert unlisted(["robot_io/config.py:RobotConfig", "experiments/plan.py:EnvSpec"], pages) == []


# -- a stale page fails ----------------------------------------------------------------------------


class _Recording(RecordingConfig):
    keep_days: int = Field(7, ge=1)  # a key added without regenerating the reference


class _Stack(StackConfig):
    recording: _Recording = _Recording()


def test_a_changed_model_makes_the_reference_stale(pages, tmp_path):
    for name, text in pages.items():
        (tmp_path / name).write_text(text)
    changed = render_pages(stack=_Stack)
    assert stale_pages(changed, tmp_path) == ["configuration.md"]
    # the new key's row, with its bounds and its comment as the description
    row = "| `recording.keep_days` | int | `7` | ≥ 1 | a key added without regenerating the reference |"
    assert row in changed["configuration.md"]
    assert row not in pages["configuration.md"]
    assert {name: text for name, text in changed.items() if name != "configuration.md"} == {
        name: text for name, text in pages.items() if name != "configuration.md"
    }


def test_an_edited_or_missing_page_is_stale_and_the_command_says_so(pages, tmp_path, capsys):
    args = argparse.Namespace(dir=str(tmp_path), check=False)
    assert reference(args) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(pages)
    assert stale_pages(pages, tmp_path) == []
    assert reference(argparse.Namespace(dir=str(tmp_path), check=True)) == 0

    page = tmp_path / "robot.md"
    page.write_text(page.read_text().replace("| `robot.control_rate_hz` | float | `20.0` |", "| x | y | z |"))
    (tmp_path / "agents.md").unlink()
    assert stale_pages(pages, tmp_path) == ["robot.md", "agents.md"]
    capsys.readouterr()
    assert reference(argparse.Namespace(dir=str(tmp_path), check=True)) == 1
    assert f"run `{COMMAND}`" in capsys.readouterr().err
    assert _stale_message(["robot.md"]).endswith(f"run `{COMMAND}` and commit the pages")

    assert reference(args) == 0  # regenerating mends them
    assert stale_pages(pages, tmp_path) == []
