"""Property tests of every config section: whatever a YAML file holds, loading it gives a valid section
or a ``ConfigError`` whose every line names the file and a key path (never another exception).
10⁴ cases; each case is applied to every section, so every section sees all of them."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import deploy.config  # noqa: F401  (imports every section of the stack)
import experiments.training  # noqa: F401
import sim.schedules  # noqa: F401
from common.config import ConfigError, Section, parse


def _all_sections(cls: type[Section] = Section) -> list[type[Section]]:
    found = []
    for sub in cls.__subclasses__():
        found += [sub, *_all_sections(sub)]
    return found


SECTIONS = sorted(set(_all_sections()), key=lambda c: c.__qualname__)
YAML_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(10**12), 10**12)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=10,
)


def test_every_section_is_covered():
    names = {c.__name__ for c in SECTIONS}
    assert {"StackConfig", "RobotConfig", "VisionConfig", "AdaptiveHConfig", "ZenohConfig"} <= names
    assert len(SECTIONS) >= 20


def _check(section: type[Section], data: object) -> None:
    try:
        parse(section, data, "f.yaml")
    except ConfigError as exc:
        lines = str(exc).splitlines()
        assert lines and all(line.startswith("f.yaml: ") and line != "f.yaml: " for line in lines), exc


@settings(max_examples=10_000, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(key_index=st.integers(0, 10_000), value=YAML_VALUES, extra=st.booleans())
def test_one_bad_value_anywhere_gives_a_clear_error(key_index: int, value: object, extra: bool) -> None:
    """A valid section (its defaults) with one key set to an arbitrary YAML value, or an unknown key."""
    for section in SECTIONS:
        fields = sorted(section.model_fields)
        if not fields:
            continue
        key = f"zz_{key_index}" if extra else fields[key_index % len(fields)]
        _check(section, {key: value})


@settings(max_examples=2_000, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(data=YAML_VALUES)
def test_whole_file_of_anything(data: object) -> None:
    for section in SECTIONS:
        _check(section, data)


@pytest.mark.parametrize("section", SECTIONS, ids=lambda c: c.__name__)
def test_bad_key_error_lists_the_allowed_keys(section: type[Section]) -> None:
    with pytest.raises(ConfigError, match=r"f.yaml: no_such_key: unknown key; allowed: \["):
        parse(section, {"no_such_key": 1}, "f.yaml")
