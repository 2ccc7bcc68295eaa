import pytest

from robot_io.config import RobotConfig
from tasks.sim_world import robot_controller


@pytest.fixture
def controller():
    c = robot_controller(RobotConfig(target_motion="static"))
    yield c
    c.close()
