"""The robot interface a Core needs, checked at construction (robots/interface.py)."""
import pytest

from robots.api import RobotAPI
from robots.interface import CAPABILITIES, RobotInterface, check_robot
from robots.world import World
from scenarios.recorder import RecordingAPI


@pytest.fixture(scope="module")
def world():
    w = World.from_file("small", seed=3)
    yield w
    w.close()


def test_simulated_robots_implement_the_interface_with_their_capabilities(world):
    nao, elektron = RobotAPI(world.add_robot("nao")), RobotAPI(world.add_robot("elektron"))
    for api in (nao, elektron, RecordingAPI(nao)):
        assert check_robot(api) is api and isinstance(api, RobotInterface)
        assert api.capabilities() <= set(CAPABILITIES)
    assert {"speech", "sonars", "head", "camera"} <= nao.capabilities() and "laser" not in nao.capabilities()
    assert "laser" in elektron.capabilities()
    assert RecordingAPI(nao).capabilities() == nao.capabilities()
    assert not nao.moving_forward()


def test_an_incomplete_robot_is_refused_naming_what_is_missing():
    class OnlyHandle:
        async def handle(self, req):
            return None

    with pytest.raises(TypeError, match="missing moving_forward, capabilities, halt, protect, microphone"):
        check_robot(OnlyHandle())
