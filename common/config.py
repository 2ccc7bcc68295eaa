"""Config sections as typed pydantic models, loaded from YAML with errors that name the key path.

Every section of every YAML file is a :class:`Section`: unknown keys are errors, values are coerced to
the declared type (YAML reads ``5e-1`` as text; ``"0.5"`` becomes a float, ``12.5`` is not an int),
ranges and closed sets are declared with ``Field``/``Literal`` rather than checked by hand, and a bad
file raises :class:`ConfigError` whose message lists each offending ``key.path``, what was given and
what is allowed.
"""

from __future__ import annotations

import re
import types
import typing
from pathlib import Path
from typing import Annotated, Any, TypeVar

import yaml
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from common.errors import AdaptiveHError

S = TypeVar("S", bound=BaseModel)


class ConfigError(AdaptiveHError, ValueError):
    """A config file or section that cannot be used; the message names the key path."""


class Section(BaseModel):
    """Base of every config section: frozen, no unknown keys, finite numbers, defaults validated too.

    Like the frozen dataclasses it replaces, a section may be built with positional arguments in field
    order (``Intrinsics(320, 240, ...)``). Built in code, a bad value raises pydantic's
    ``ValidationError`` (a ``ValueError`` listing each key); :func:`parse` turns it into a ConfigError.
    """

    model_config = ConfigDict(
        extra="forbid", frozen=True, validate_default=True, allow_inf_nan=False, use_enum_values=True
    )

    def __init__(self, /, *args: Any, **data: Any) -> None:
        if args:
            names = list(type(self).model_fields)
            if len(args) > len(names):
                raise TypeError(f"{type(self).__name__} takes at most {len(names)} positional arguments")
            twice = sorted(set(names[: len(args)]) & set(data))
            if twice:
                raise TypeError(f"{type(self).__name__} got {twice} both by position and by name")
            data = {**dict(zip(names, args, strict=False)), **data}
        super().__init__(**data)


def _lo_below_hi(box: tuple[tuple[float, ...], tuple[float, ...]]) -> tuple[tuple[float, ...], ...]:
    if any(lo >= hi for lo, hi in zip(*box, strict=True)):
        raise ValueError(f"lo {list(box[0])} must be below hi {list(box[1])} on every axis")
    return box


Vec3 = Annotated[tuple[float, ...], Field(min_length=3, max_length=3)]
"""Three finite numbers (a YAML list becomes a tuple)."""
Box3 = Annotated[tuple[Vec3, Vec3], AfterValidator(_lo_below_hi)]
"""``[[x, y, z] lo, [x, y, z] hi]`` with lo < hi on every axis."""


def check_box(lo: tuple[float, ...], hi: tuple[float, ...]) -> None:
    """The Box3 invariant for a section that keeps ``lo`` and ``hi`` as two keys."""
    _lo_below_hi((lo, hi))


def load_yaml(path: str | Path) -> dict[str, Any]:
    """The top-level mapping of a YAML file, or a ConfigError saying why not."""
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


def overlay(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``over`` laid on ``base``: mappings merge key by key (recursively); anything else replaces."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = overlay(out[key], value)
        else:
            out[key] = value
    return out


def compose_yaml(
    path: str | Path,
    expand: typing.Callable[[dict[str, Any], Path], dict[str, Any]] | None = None,
    _chain: tuple[Path, ...] = (),
) -> dict[str, Any]:
    """The YAML at ``path`` laid over the file its ``base:`` key names, if any (recursively; ``base`` is
    relative to the folder of the file that names it). ``expand(data, path)`` resolves a file's own
    references before it is laid over its base."""
    data = load_yaml(path)
    if expand is not None:
        data = expand(data, Path(path))
    ref = data.pop("base", None)
    if ref is None:
        return data
    if not isinstance(ref, str):
        raise ConfigError(f"{path}: base: expected a config file name, got {ref!r}")
    here = Path(path).resolve()
    base = here.parent / ref
    if base.resolve() in (*_chain, here):
        raise ConfigError(f"{path}: base: {ref} includes itself")
    try:
        return overlay(compose_yaml(base, expand, (*_chain, here)), data)
    except ConfigError as exc:
        raise ConfigError(f"{path}: base: {exc}") from None


def _model_in(annotation: Any) -> type[BaseModel] | None:
    """The section type inside an annotation (``Pose | None``, ``Annotated[Pose, ...]``), if any."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if typing.get_origin(annotation) in (typing.Union, types.UnionType, Annotated):
        for arg in typing.get_args(annotation):
            found = _model_in(arg)
            if found is not None:
                return found
    return None


def _allowed_keys(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """The field names of the (nested) section that owns the unknown key at ``loc``."""
    current: type[BaseModel] | None = model
    for part in loc[:-1]:
        if current is None or part not in current.model_fields:
            return []
        current = _model_in(current.model_fields[part].annotation)
    return sorted(current.model_fields) if current is not None else []


def _key(part: Any) -> str:
    """A key as the error shows it: quoted when it is not plain printable text (a control character in
    a key must not split or garble the one-line error)."""
    text = str(part)
    return text if text and text.isprintable() and text.strip() == text and "." not in text else repr(text)


_ENUM_MEMBER = re.compile(r"<\w+\.\w+: ('[^']*')>")  # pydantic names a Literal's enum members so; YAML's word


def describe(exc: ValidationError, model: type[BaseModel], where: str = "") -> str:
    """One line per error: ``where: key.path: what is wrong (got X)``, with allowed keys for unknown ones."""
    prefix = f"{where}: " if where else ""
    errors = exc.errors()
    deeper = {tuple(e["loc"][:i]) for e in errors for i in range(len(e["loc"]))}
    lines = []
    for err in errors:
        if err["type"] == "too_short" and tuple(err["loc"]) in deeper:
            continue  # "0 items" only because an item inside failed, which is reported itself
        path = ".".join(_key(p) for p in err["loc"]) or "(top level)"
        if err["type"] == "extra_forbidden":
            allowed = _allowed_keys(model, tuple(err["loc"]))
            lines.append(f"{prefix}{path}: unknown key; allowed: {allowed}")
            continue
        got = err.get("input")
        shown = "" if isinstance(got, dict) else f" (got {got!r})"
        # An invariant's own words, without pydantic's "Value error, " in front.
        own = err["type"] == "value_error"
        msg = str(err["ctx"]["error"]) if own else _ENUM_MEMBER.sub(r"\1", err["msg"])
        lines.append(f"{prefix}{path}: {'; '.join(msg.splitlines())}{shown}")
    return "\n".join(lines)


def parse(model: type[S], data: Any, where: str) -> S:
    """Validate ``data`` (None means all defaults) as ``model``; a ConfigError names every bad key."""
    try:
        return model.model_validate({} if data is None else data)
    except ValidationError as exc:
        raise ConfigError(describe(exc, model, where)) from None
