"""The configuration reference (``docs/reference/``): every key a user writes in YAML, generated from the
config models so that it cannot drift from them.

``adaptiveh config reference`` rewrites the pages; tests/common/test_config_reference.py fails when a
model changed and the pages were not regenerated, when a key has no description, and when a config model
of the project is in no page. A key's description is read from the model's source:
the ``#`` comment on the key's line and the comment lines directly above it; else its ``Field``
description; else the sentence of the model's docstring that starts with the key (in double backticks)
and a colon. Bounds are the ``Field`` constraints
(gt, ge, lt, le, lengths, patterns) and the ``Literal`` choices; checks across keys (lo below hi, ...)
are the models' validators and are not listed.
"""

from __future__ import annotations

import ast
import functools
import inspect
import io
import re
import textwrap
import tokenize
import types
import typing
import unicodedata
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel
from pydantic.fields import FieldInfo

ROOT = Path(__file__).resolve().parent.parent
REFERENCE_DIR = ROOT / "docs" / "reference"
COMMAND = "adaptiveh config reference"
OWN_PAGE = {"robot": "robot.md", "vision": "vision.md"}  # the big sections; the rest share MAIN_PAGE
MAIN_PAGE = "configuration.md"
AGENTS_PAGE = "agents.md"
SEE_ALSO = {  # where the keys of a free-form mapping are listed
    "learner.agent": f"its keys: [learner.agent]({AGENTS_PAGE}), those of ``algo``",
    "agent": "its keys: those of learner.agent above, for ``algo``",
}
_LIMITS = ("gt", "ge", "lt", "le", "min_length", "max_length", "pattern")
_CODE = re.compile(r"(``.+?``|`[^`]+`)")
_INTRAWORD_STAR = re.compile(r"(?<=[\w)\]])\*(?=[\w(\[])")
_SCALARS = {bool: "bool", int: "int", float: "float", str: "str", type(None): "null", Any: "any", Path: "str"}


@dataclass(frozen=True)
class Row:
    key: str
    type: str
    default: str
    bounds: str
    description: str


@dataclass(frozen=True)
class Table:
    """One model where it sits in a config: its heading (the key path), the model and one row per key."""

    heading: str
    model: type[BaseModel]
    rows: tuple[Row, ...]
    level: int = 2


# -- descriptions from the source ------------------------------------------------------------------


@functools.cache
def _own_comments(cls: type) -> dict[str, str]:
    """The keys declared in ``cls``'s own body, with their comments (those above, then the trailing one)."""
    try:
        source = textwrap.dedent("".join(inspect.getsourcelines(cls)[0]))
    except (OSError, TypeError):  # built at run time: no source to read
        return {}
    classdef = ast.parse(source).body[0]
    comments: dict[int, str] = {}
    code: set[int] = set()
    skip = {tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.ENDMARKER}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string.lstrip("#").strip()
        elif tok.type not in skip:
            code.update(range(tok.start[0], tok.end[0] + 1))
    out = {}
    for stmt in getattr(classdef, "body", []):
        if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
            continue
        above, line = [], stmt.lineno - 1
        while line in comments and line not in code:
            above.insert(0, comments[line])
            line -= 1
        trailing = [
            comments[n] for n in range(stmt.lineno, (stmt.end_lineno or stmt.lineno) + 1) if n in comments
        ]
        out[stmt.target.id] = " ".join(above + trailing)
    return out


def _docstring_entries(cls: type) -> dict[str, str]:
    """The entries of ``cls``'s own docstring that start with a key in double backticks and a colon, each up
    to the line that ends its sentence."""
    doc = inspect.cleandoc(cls.__dict__.get("__doc__") or "")
    out: dict[str, str] = {}
    key = None
    for line in doc.splitlines():
        found = re.match(r"``(\w+)``:\s*(.*)", line.strip())
        if found:
            key, text = found.group(1), found.group(2)
            out[key] = text
        elif key is not None and line.strip():
            out[key] += " " + line.strip()
        else:
            key = None
        if key is not None and out[key].endswith("."):
            key = None
    return out


def description(model: type[BaseModel], name: str) -> str:
    """What the source says of ``model``'s key ``name`` ("" when nothing)."""
    for cls in model.__mro__:
        comments = _own_comments(cls) if isinstance(cls, type) and issubclass(cls, BaseModel) else {}
        if name in comments:
            if comments[name]:
                return comments[name]
            break
    info = model.model_fields[name]
    if info.description:
        return info.description
    for cls in model.__mro__:
        entry = _docstring_entries(cls).get(name)
        if entry:
            return entry
    return ""


def docstring(model: type[BaseModel]) -> list[str]:
    """``model``'s own docstring, one line per paragraph."""
    doc = inspect.cleandoc(model.__dict__.get("__doc__") or "")
    return [" ".join(p.split()) for p in doc.split("\n\n") if p.strip()]


# -- types, bounds and defaults ------------------------------------------------------------------


def _limits(metadata: Iterable[Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in metadata:
        if isinstance(item, FieldInfo):
            out.update(_limits(item.metadata))
            continue
        for name in _LIMITS:
            value = getattr(item, name, None)
            if value is not None:
                out[name] = value
    return out


def _num(value: Any) -> str:
    return repr(value)


def _bounds(limits: dict[str, Any], text: bool = False) -> list[str]:
    """``limits`` in words: ``0 < x ≤ 1``, ``≥ 1``, ``3 items``, ``matches `re```."""
    out = []
    lo = ("<", limits["gt"]) if "gt" in limits else ("≤", limits["ge"]) if "ge" in limits else None
    hi = ("<", limits["lt"]) if "lt" in limits else ("≤", limits["le"]) if "le" in limits else None
    if lo and hi:
        out.append(f"{_num(lo[1])} {lo[0]} x {hi[0]} {_num(hi[1])}")
    elif lo:
        out.append(f"{'>' if lo[0] == '<' else '≥'} {_num(lo[1])}")
    elif hi:
        out.append(f"{hi[0]} {_num(hi[1])}")
    n, m = limits.get("min_length"), limits.get("max_length")
    size = "length " if text else ""
    unit = "" if text else " item" if (m if n is None else n) == 1 else " items"
    if n is not None and n == m:
        out.append(f"{size}{n}{unit}")
    else:
        if n is not None:
            out.append(f"{size}≥ {n}{unit}")
        if m is not None:
            out.append(f"{size}≤ {m}{unit}")
    if "pattern" in limits:
        out.append(f"matches `{limits['pattern']}`")
    return out


def _yaml(value: Any) -> str:
    """``value`` as YAML writes it on one line (tuples as lists)."""

    def plain(v: Any) -> Any:
        if isinstance(v, BaseModel):
            return {k: plain(x) for k, x in v.model_dump().items()}
        if isinstance(v, tuple | list):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {plain(k): plain(x) for k, x in v.items()}
        if isinstance(v, Enum):
            return v.value
        if isinstance(v, Path):
            return str(v)
        return v

    text = yaml.safe_dump(
        plain(value), default_flow_style=True, sort_keys=False, width=10_000, allow_unicode=True
    )
    return text.removesuffix("\n").removesuffix("\n...").strip()


def describe_type(annotation: Any, metadata: Iterable[Any] = ()) -> tuple[str, str]:
    """(type, bounds) of a key declared as ``annotation`` with ``Field`` ``metadata``, in YAML's words:
    ``list`` for a sequence (a tuple too), ``map`` for a mapping, ``null`` for None."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is Annotated:
        return describe_type(args[0], (*annotation.__metadata__, *metadata))
    limits = _limits(metadata)
    if origin in (typing.Union, types.UnionType):
        # A constraint on ``float | None`` holds for the float: pass it to each alternative.
        parts = [describe_type(a, () if a is type(None) else metadata) for a in args]
        bounded = [(t, b) for t, b in parts if b]
        if len(bounded) == 1:
            bounds = bounded[0][1]
        else:
            bounds = "; ".join(f"{t}: {b}" for t, b in bounded)
        return " | ".join(dict.fromkeys(t for t, _ in parts)), bounds
    if origin is Literal:
        values = [v.value if isinstance(v, Enum) else v for v in args]
        kinds = dict.fromkeys(_SCALARS.get(type(v), type(v).__name__) for v in values)
        return " | ".join(kinds), "one of " + ", ".join(f"`{_yaml(v)}`" for v in args)
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation.__name__, ""
    if origin is dict:
        key, value = (describe_type(a) for a in args) if args else (("str", ""), ("any", ""))
        notes = [f"keys {key[1]}"] if key[1] else []
        notes += [f"values {value[1]}"] if value[1] else []
        return f"map[{key[0]}, {value[0]}]", "; ".join(_bounds(limits) + notes)
    if origin in (list, tuple, set, frozenset) or annotation in (list, tuple, set, frozenset):
        own = _bounds(limits)
        if origin is tuple and args and args[-1] is not Ellipsis:  # fixed length, one type per place
            parts = [describe_type(a) for a in args]
            kind = "[" + ", ".join(t for t, _ in parts) + "]"
            each = {b for _, b in parts}
            if each == {""}:
                items = ""
            elif len(each) == 1:
                items = f"each {each.pop()}"
            else:
                items = "by place: " + ", ".join(b or "any" for _, b in parts)
        else:
            item, items = describe_type(args[0]) if args else ("any", "")
            kind = f"list[{item}]"
            items = f"each {items}" if items else ""
        return kind, "; ".join(own + ([items] if items else []))
    if annotation in _SCALARS:
        return _SCALARS[annotation], "; ".join(_bounds(limits, text=annotation is str))
    return getattr(annotation, "__name__", str(annotation)), "; ".join(_bounds(limits))


def section_model(annotation: Any) -> type[BaseModel] | None:
    """The model of a key that is a section of its own (``Pose``, ``Pose | None``), else None."""
    if typing.get_origin(annotation) is Annotated:
        return section_model(typing.get_args(annotation)[0])
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        models = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(models) == 1:
            return section_model(models[0])
    return None


def item_model(annotation: Any) -> type[BaseModel] | None:
    """The model of each item of a key that is a list of sections (``tuple[ArmConfig, ...]``), else None."""
    if typing.get_origin(annotation) is Annotated:
        return item_model(typing.get_args(annotation)[0])
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) in (list, tuple) and args and args[-1] in (Ellipsis, args[0]):
        return section_model(args[0])
    return None


# -- tables and pages ------------------------------------------------------------------------------


def slug(heading: str) -> str:
    """The anchor Python-Markdown's toc gives ``heading`` (its default slugify)."""
    text = unicodedata.normalize("NFKD", heading).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def _escape(text: str, cell: bool = True) -> str:
    """``text`` as markdown that shows it as written (code spans kept): ``<`` and a ``*`` inside a word
    (``2*3``) escaped, and in a table ``cell`` ``|``."""
    out = []
    for i, part in enumerate(_CODE.split(text)):
        if i % 2 == 0:
            part = _INTRAWORD_STAR.sub(r"\\*", part.replace("\\", "\\\\")).replace("<", "&lt;")
            part = part.replace("|", "\\|") if cell else part
        out.append(part)
    return "".join(out)


def tables(
    model: type[BaseModel],
    path: str,
    instance: BaseModel | None,
    link: Callable[[str], str],
    level: int = 2,
) -> list[Table]:
    """``model``'s table at ``path`` (``robot.franka``), then its sections', depth first. Defaults are
    ``instance``'s values (the parent's default of this section), else the model's own."""
    rows, below = [], []
    for name, info in model.model_fields.items():
        key = f"{path}.{name}" if path else name
        if instance is not None:
            value, required = getattr(instance, name), False
        else:
            required = info.is_required()
            value = None if required else info.get_default(call_default_factory=True)
        text = description(model, name)
        if key in SEE_ALSO:
            text = (
                f"{text.rstrip('.')}; {SEE_ALSO[key]}."
                if text
                else f"{SEE_ALSO[key][0].upper()}{SEE_ALSO[key][1:]}."
            )
        sub = section_model(info.annotation)
        if sub is not None:
            optional = sub is not info.annotation and typing.get_origin(info.annotation) is not Annotated
            kind = f"[section]({link(key)})" + (" \\| null" if optional else "")
            shown = "required" if required else "`null`" if value is None else "see below"
            rows.append(Row(key, kind, shown, "", _escape(text)))
            nested = value if isinstance(value, BaseModel) else None
            below += tables(sub, key, nested, link, level=3)
            continue
        kind, bounds = describe_type(info.annotation, info.metadata)
        shown = "required" if required else f"`{_yaml(value)}`"
        rows.append(Row(key, _escape(kind), shown, bounds, _escape(text)))
        each = item_model(info.annotation)
        if each is not None:  # a list of sections: each item's keys, below (``fleet.arms.name``)
            below += tables(each, key, None, link, level=3)
    return [Table(path, model, tuple(rows), level), *below]


def _render_table(table: Table, heading: str | None = None) -> list[str]:
    model = table.model
    where = inspect.getsourcefile(model) or ""
    try:
        where = Path(where).resolve().relative_to(ROOT).as_posix()
    except ValueError:
        where = Path(where).name
    paragraphs = docstring(model)
    intro = f"`{model.__name__}` (`{where}`)" + (
        f": {_escape(paragraphs[0], cell=False)}" if paragraphs else "."
    )
    lines = [f"{'#' * table.level} {heading or table.heading}", "", intro, ""]
    for para in paragraphs[1:]:
        lines += [_escape(para, cell=False), ""]
    lines += ["| key | type | default | bounds | description |", "|---|---|---|---|---|"]
    for r in table.rows:
        lines.append(f"| `{r.key}` | {r.type} | {r.default} | {r.bounds} | {r.description} |")
    return [*lines, ""]


HEADER = (
    "*Generated from the config models by `{command}`: edit the models (a key's `#` comment or its `Field`"
    " description is its description), then rerun it; tests/common/test_config_reference.py fails while"
    " this page is stale or a key has no description.*"
)
LEGEND = """\
A key left out takes its default. An unknown key, a value of the wrong type or one outside its bounds
stops the part at start-up with an error naming the key's path; checks across keys (lo below hi, a
camera that needs a simulated arm, ...) are the models' validators and are not listed here. **type** is
in YAML's words: `list` for a sequence, `map` for a mapping, `null` for none (`A | B`: either), and a
number is finite (no `.inf` or `.nan`); **default** `required` means the key has none; in **bounds** `x`
is the value.
"""


def render_pages(
    stack: type[BaseModel] | None = None,
    agents: dict[str, type[BaseModel]] | None = None,
    task: type[BaseModel] | None = None,
) -> dict[str, str]:
    """The reference pages, file name -> markdown: the stack config (its top level and small sections,
    then one page per big section) and ``learner.agent`` per algorithm with the task config of
    ``adaptiveh train``. The models default to the project's; a test passes changed ones."""
    if stack is None:
        from deploy.config import StackConfig as stack
    if agents is None:
        from learner.config import AGENT_CONFIGS as agents
    if task is None:
        from experiments.training import TrainSpec as task

    def page_of(key: str) -> str:
        return OWN_PAGE.get(key.split(".")[0], MAIN_PAGE)

    def link_from(page: str) -> Callable[[str], str]:
        return lambda key: ("" if page_of(key) == page else page_of(key)) + "#" + slug(key)

    default = stack()
    top = tables(stack, "", default, link_from(MAIN_PAGE))[0]
    sections = {}  # top-level key -> its tables, linked for the page they are on
    for name, info in stack.model_fields.items():
        model = section_model(info.annotation)
        if model is not None:
            value = getattr(default, name)
            nested = value if isinstance(value, BaseModel) else None
            sections[name] = tables(model, name, nested, link_from(page_of(name)))
    shared = ", ".join(f"[{name}](#{slug(name)})" for name in sections if page_of(name) == MAIN_PAGE)
    pages: dict[str, list[str]] = {
        MAIN_PAGE: [
            "# Configuration reference",
            "",
            HEADER.format(command=COMMAND),
            "",
            "Every key of a stack config (`configs/sim.yaml`: what every part and `adaptiveh up` read;"
            " `adaptiveh config show FILE` prints one with its overlays resolved), on these pages:",
            "",
            f"- this page: the top level and the sections {shared}",
            *(f"- [{key}]({page}): the `{key}:` section" for key, page in OWN_PAGE.items()),
            f"- [learner.agent]({AGENTS_PAGE}): each algorithm's hyperparameters, and the task configs of"
            " `adaptiveh train`",
            "",
            LEGEND,
            *_render_table(top, heading="Top level"),
        ]
    }
    for name, found in sections.items():
        page = page_of(name)
        if page not in pages:
            pages[page] = [f"# {name}", "", HEADER.format(command=COMMAND), "", LEGEND]
        for table in found:
            pages[page] += _render_table(table)
    pages[AGENTS_PAGE] = _agents_page(agents, task)
    return {name: "\n".join(lines).rstrip("\n") + "\n" for name, lines in pages.items()}


def _agents_page(agents: dict[str, type[BaseModel]], task: type[BaseModel]) -> list[str]:
    lines = [
        "# learner.agent",
        "",
        HEADER.format(command=COMMAND),
        "",
        "The hyperparameters of each algorithm: a stack config's `learner.agent` (checked against"
        " `learner.algo` when the config loads), or a task config's `agent:` (the same keys; e.g."
        " `configs/reach.yaml`, which `learner.agent_from` can name). In a stack config `execution` and"
        " `latency_steps` are refused: `learner.execution` and `learner.latency_ms` set them.",
        "",
        LEGEND,
    ]
    by_model: dict[type[BaseModel], list[str]] = {}
    for algo, model in agents.items():
        by_model.setdefault(model, []).append(algo)
    for model, algos in by_model.items():
        heading = f"learner.agent for {', '.join(algos)}"
        for table in tables(model, "learner.agent", None, lambda key: "#" + slug(key)):
            lines += _render_table(table, heading=heading if table.heading == "learner.agent" else None)
    task_table = tables(task, "", None, lambda key: "#" + slug(key))[0]
    lines += _render_table(task_table, heading="Task configs (adaptiveh train --config)")
    return lines


def stale_pages(pages: dict[str, str], directory: Path = REFERENCE_DIR) -> list[str]:
    """The pages whose file in ``directory`` is missing or differs from ``pages``."""
    return [
        name
        for name, text in pages.items()
        if not (directory / name).is_file() or (directory / name).read_text() != text
    ]


def write_pages(pages: dict[str, str], directory: Path = REFERENCE_DIR) -> list[Path]:
    """Write the pages that changed; returns them."""
    directory.mkdir(parents=True, exist_ok=True)
    changed = stale_pages(pages, directory)
    for name in changed:
        (directory / name).write_text(pages[name])
    return [directory / name for name in changed]


if __name__ == "__main__":
    for path in write_pages(render_pages()):
        print(f"wrote {path}")
