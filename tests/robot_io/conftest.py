import pytest

from robot_io.config import RobotConfig
from robot_io.controller import RobotController


@pytest.fixture
def controller():
    c = RobotController(RobotConfig(target_motion="static"))
    yield c
    c.close()
