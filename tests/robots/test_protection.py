"""The robot's own collision protection (RobotInterface.protect): a forward motion stops before the
body touches what the range sensors see ahead, checked in simulated time however fast the world runs;
range readings say where their sensor sits, so obstacle positions are taken from the base's centre."""
from __future__ import annotations

import math

import pytest

from ontology.robot import GetLaserScan, GetSonars, MoveTo
from robots import MotionBlocked

from .conftest import api_at

BOX = {"kind": "box", "id": "crate", "at": 0.0, "position": [2.0, 2.0], "size": [0.3, 0.6, 0.8]}


@pytest.mark.parametrize("kind", ["nao", "elektron"])
async def test_protection_stops_short_of_a_box_and_off_drives_into_it(make_world, kind):
    world = make_world("small", render="inline", disturbances=[BOX])
    api = api_at(world, kind, (1.0, 2.0, 0))
    api.protect(0.10)
    with pytest.raises(MotionBlocked, match="collision protection"):
        await api.move_to(MoveTo(x=1.5, y=0.0, theta=0.0))
    x = world.ground_truth().robots[kind][0]
    gap = 2.0 - 0.15 - (x + world.robots[kind].spec.radius)  # between the body and the box's near face
    assert 0.02 < gap < 0.3 and world.object_contacts() == 0  # the NAO: its sonars see nothing nearer than 0.25 m
    api.protect(None)  # off: the base drives on until it touches
    with pytest.raises(MotionBlocked, match="blocked the base"):
        await api.move_to(MoveTo(x=0.5, y=0.0, theta=0.0))
    assert world.object_contacts() == 1


async def test_readings_say_where_their_sensors_sit(make_world):
    world = make_world("small", render="inline")
    laser = await api_at(world, "elektron", (1.0, 1.0, 30)).handle(GetLaserScan())
    sonars = await api_at(world, "nao", (1.0, 3.0, -60)).handle(GetSonars())
    assert laser.mount_x == pytest.approx(0.16, abs=0.005)
    assert 0.02 < sonars.mount_x < 0.1 and sonars.bearing == pytest.approx(math.radians(25), abs=0.01)
