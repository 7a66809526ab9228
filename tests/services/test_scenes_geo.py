"""Scene recognition (which room of the home a robot's camera sees, agents/services/scenes.py),
validated on a generated house, and the offline geolocation provider (agents/services/geolocation.py)."""
from __future__ import annotations

import math
import random

import numpy as np
import pytest

from agents.services import geolocation, scenes
from agents.services.errors import ServiceError
from agents.services.images import encode_image
from ontology.services.information import Geolocate
from ontology.services.vision import ForgetScenes, LearnScene, RecognizeScene

LOOK = 4  # a look-around: four headings, 90 degrees apart


def places(plan, rng: random.Random, n: int) -> dict[str, list[tuple[float, float, float]]]:
    """n free spots per room (0.45 m from anything), each with a random heading."""
    out = {}
    for room in plan.rooms:
        x0, y0, x1, y1 = room.rect
        spots = []
        for _ in range(500):
            x, y = rng.uniform(x0 + 0.3, x1 - 0.3), rng.uniform(y0 + 0.3, y1 - 0.3)
            if plan.clearance(x, y) > 0.45:
                spots.append((x, y, rng.uniform(-math.pi, math.pi)))
            if len(spots) == n:
                break
        out[room.name] = spots
    return out


async def look_around(world, robot, api, pose) -> list[str]:
    from ontology.robot import CaptureImage

    shots = []
    for k in range(LOOK):
        world.run_sync(robot.set_base_pose, pose[0], pose[1], pose[2] + k * 2 * math.pi / LOOK)
        shots.append((await api.capture_image(CaptureImage(resolution="320x240"))).data_b64)
    return shots


async def test_the_room_is_recognized_from_a_look_around_in_a_generated_house(ctx):
    """Learned from a look-around at 3 places per room, asked at 4 other places per room of a house
    generated from a seed drawn at run time: twice as many right answers as chance at least (it had
    75-88 % right over 32-40 places a house, docs/scene-recognition.md; this test's answers vary too
    much to assert that. With 2 places a room asked, house 4073 failed it in CI at 3 of 6)."""
    from robots import RobotAPI, World

    seed = random.randrange(1, 10_000)
    world = World.from_file("generated", seed=seed)
    try:
        robot = world.add_robot("nao")
        api = RobotAPI(robot)
        spots = places(world.plan, random.Random(seed), 7)
        asked = []
        for room, poses in spots.items():
            for i, pose in enumerate(poses):
                shots = await look_around(world, robot, api, pose)
                if i < 3:
                    scenes.learn_scene(LearnScene(room=room, images_b64=shots), ctx)
                else:
                    asked.append((room, shots))
        right = [scenes.recognize_scene(RecognizeScene(images_b64=shots), ctx).room == room for room, shots in asked]
        chance = 1 / len(spots)
        assert len(asked) >= 4 and sum(right) >= 2 * chance * len(right), (seed, sum(right), len(right))
    finally:
        world.close()


def test_views_are_per_user_and_home_and_forgotten(ctx):
    from agents.services.context import ServiceContext

    rng = np.random.default_rng(1)
    red = np.zeros((120, 160, 3), np.uint8)
    red[:, :, 2] = 200
    red[40:80, 60:100] = rng.integers(0, 255, (40, 40, 3))
    blue = np.zeros((120, 160, 3), np.uint8)
    blue[:, :, 0] = 200
    blue[20:100, 20:60] = rng.integers(0, 255, (80, 40, 3))
    scenes.learn_scene(LearnScene(room="kitchen", images_b64=[encode_image(red)]), ctx)
    scenes.learn_scene(LearnScene(room="bedroom", images_b64=[encode_image(blue)]), ctx)
    reply = scenes.recognize_scene(RecognizeScene(images_b64=[encode_image(red)]), ctx)
    assert reply.room == "kitchen" and reply.distance < 0.01 and [c.room for c in reply.candidates] == ["kitchen", "bedroom"]
    grey = encode_image(np.full((120, 160, 3), 128, np.uint8))
    assert scenes.recognize_scene(RecognizeScene(images_b64=[grey], max_distance=0.05), ctx).room == ""
    with pytest.raises(ServiceError, match="no rooms learned yet for home 'flat'"):
        scenes.recognize_scene(RecognizeScene(images_b64=[grey], home_id="flat"), ctx)
    with pytest.raises(ServiceError, match="no rooms learned"):
        scenes.recognize_scene(RecognizeScene(images_b64=[grey]), ServiceContext(user="bob", state=ctx.state))
    scenes.forget_scenes(ForgetScenes(room="kitchen"), ctx)
    assert scenes.recognize_scene(RecognizeScene(images_b64=[encode_image(red)]), ctx).candidates[0].room == "bedroom"
    scenes.forget_scenes(ForgetScenes(), ctx)
    with pytest.raises(ServiceError, match="no rooms learned"):
        scenes.recognize_scene(RecognizeScene(images_b64=[grey]), ctx)


@pytest.mark.parametrize("ip,city,source", [("192.0.2.17", "Krakow", "ip-table"), ("2001:db8::5", "Paris", "ip-table"),
                                            ("10.1.2.3", "Warsaw", "platform"), ("127.0.0.1", "Warsaw", "platform")])
def test_an_address_is_located_from_the_offline_table(ctx, ip, city, source):
    where = geolocation.geolocate(Geolocate(ip=ip), ctx)
    assert (where.city, where.source) == (city, source)


def test_a_time_zone_is_located_at_its_principal_city_and_bad_input_is_refused(ctx):
    where = geolocation.geolocate(Geolocate(timezone="America/New_York"), ctx)
    assert (where.city, where.country_code, where.country) == ("New York", "US", "United States")
    assert where.latitude == pytest.approx(40.714, abs=0.01) and where.longitude == pytest.approx(-74.006, abs=0.01)
    assert geolocation.geolocate(Geolocate(), ctx).source == "platform"
    with pytest.raises(ServiceError, match="not an IP address") as e:
        geolocation.geolocate(Geolocate(ip="300.1.1.1"), ctx)
    assert e.value.code == "invalid_argument"
    with pytest.raises(ServiceError, match="no place known for 8.8.8.8") as e:
        geolocation.geolocate(Geolocate(ip="8.8.8.8"), ctx)
    assert e.value.code == "not_found"
    with pytest.raises(ServiceError, match="unknown time zone"):
        geolocation.geolocate(Geolocate(timezone="Mars/Olympus"), ctx)
