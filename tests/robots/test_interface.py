"""The robot interface a Core needs, checked at construction (robots/interface.py)."""
import numpy as np
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

    with pytest.raises(TypeError, match="missing moving_forward, capabilities, halt, protect, microphone, "
                                        "odometry_counters, loudspeaker_timing"):
        check_robot(OnlyHandle())


def test_the_loudspeakers_timing_is_told_through_the_interface(world):
    """What the Core cuts its own voice by (agents/core_hearing.py): asked of the interface, never of the
    simulated robot behind it."""
    nao = RobotAPI(world.add_robot("nao", "nao-timing"))
    timing = nao.loudspeaker_timing()
    assert timing is not None and timing.now() == world.time
    t = world.time + 1.0
    seconds = nao.robot.loudspeaker.play(np.full(1600, 1000, np.int16), t)  # 0.1 s from t
    assert timing.sounding_until(t - 0.5, t) == pytest.approx(t + seconds)
    assert timing.sounding_until(t, t, tail=0.3) == pytest.approx(t + seconds + 0.3)
    assert timing.sounding_until(t - 0.5, t - 0.1) is None and timing.sounding_until(t + 1.0, t + 2.0) is None
    assert RecordingAPI(nao).loudspeaker_timing() is timing
    for kind in ("nao", "elektron"):
        api = RobotAPI(world.add_robot(kind, f"{kind}-speech"))
        assert (api.loudspeaker_timing() is None) == ("speech" not in api.capabilities())
