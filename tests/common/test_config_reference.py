"""The configuration reference (docs/reference/) says what the config models say now, and lists every key
of every model a user writes in YAML. After changing a model: ``adaptiveh config reference``."""

from __future__ import annotations

import argparse
import re
import typing

import pytest
from pydantic import BaseModel, Field

from deploy.commands.config import reference
from deploy.config import RecordingConfig, StackConfig
from deploy.config_reference import COMMAND, REFERENCE_DIR, render_pages, stale_pages
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
