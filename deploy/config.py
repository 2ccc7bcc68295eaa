"""Building validated config dataclasses from YAML, with errors that name the offending key."""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml

T = TypeVar("T")


class ConfigError(ValueError):
    """A config file or section that cannot be used; the message names the key."""


def load_yaml(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such config file")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: top level must be a mapping, got {type(data).__name__}")
    return data


def build(cls: type[T], data: dict[str, Any] | None, where: str) -> T:
    """Instantiate dataclass ``cls`` from ``data``, recursing into nested dataclass fields.

    Unknown keys and values rejected by the dataclass's own ``__post_init__`` checks become a
    ``ConfigError`` that says ``where.key``.
    """
    data = dict(data or {})
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping")
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(fields)}")
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for name, value in data.items():
        hint = hints[name]
        if dataclasses.is_dataclass(hint) and isinstance(value, dict):
            value = build(hint, value, f"{where}.{name}")
        kwargs[name] = value
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from None


def robot_name(data: dict[str, Any], path: str | Path) -> str:
    """The top-level ``name``: one Zenoh key segment, shared by every part of one robot's stack."""
    name = data.get("name", "panda")
    if not isinstance(name, str) or not name or "/" in name or "*" in name:
        raise ConfigError(f"{path}: name must be a non-empty key segment (no '/' or '*'), got {name!r}")
    return name
