import types

import fake_pylibfranka  # noqa: I001  (tests/robot_io is on sys.path: pytest's rootdir-less prepend mode)
import pytest

from robot_io.config import RobotConfig
from robot_io.controller import RobotController


@pytest.fixture
def fake_franka() -> types.ModuleType:
    return fake_pylibfranka


@pytest.fixture
def controller():
    c = RobotController(RobotConfig(target_motion="static"))
    yield c
    c.close()
