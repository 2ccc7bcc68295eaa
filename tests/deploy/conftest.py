"""Fixtures for the tests that start the whole stack."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from stack_helpers import write_stack_config


@pytest.fixture(scope="session")
def stack_config() -> Callable[..., tuple[Path, dict]]:
    return write_stack_config
