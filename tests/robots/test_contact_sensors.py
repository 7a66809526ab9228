"""The NAO's contact sensors (robots/contact_sensors.py): foot bumpers pressed by real contacts in the world
(walking into a wall, a low box the sonars do not see), touch sensors pressed through World.touch, both
read through get_contacts with numbered changes."""
import pytest

from ontology.robot import GetContacts, MoveTo
from robots import InvalidArgument, MotionBlocked, UnsupportedOperation

from .conftest import api_at


async def _walk(api, x):
    try:
        await api.move_to(MoveTo(x=x))
        return False
    except MotionBlocked:
        return True


async def test_walking_into_a_wall_presses_both_bumpers_then_standing_releases_them(small):
    nao = api_at(small, "nao", (2.8, 2.4, 0))  # the inner wall's face is 0.65 m ahead
    start = await nao.get_contacts(GetContacts())
    assert start.changes == [] and set(start.pressed) == {"bumper_left", "bumper_right", "head_front", "head_middle",
                                                           "head_rear", "hand_left", "hand_right"}
    assert await _walk(nao, 1.0)
    hit = await nao.get_contacts(GetContacts(after=start.last))
    assert hit.pressed["bumper_left"] and hit.pressed["bumper_right"]
    assert {(c.sensor, c.kind, c.pressed) for c in hit.changes} == {("bumper_left", "bumper", True),
                                                                    ("bumper_right", "bumper", True)}
    x = small.ground_truth().robots["nao"][0]
    assert x > 3.2 and all(c.stamp <= small.time for c in hit.changes)
    await small.sleep(0.1)  # standing: the feet are back under the body, off the wall
    after = await nao.get_contacts(GetContacts(after=hit.last))
    assert [(c.sensor, c.pressed) for c in after.changes] == [("bumper_left", False), ("bumper_right", False)]
    assert await nao.get_contacts(GetContacts(after=after.last)) == after.model_copy(update={"changes": []})


async def test_walking_in_the_open_presses_nothing(small):
    nao = api_at(small, "nao", (1.0, 2.4, 0))
    assert not await _walk(nao, 1.0)
    assert (await nao.get_contacts(GetContacts(after=0))).changes == []


async def test_a_low_box_below_the_sonars_presses_a_bumper(make_world):
    toy = {"kind": "box", "id": "toy", "at": 0.0, "position": [2.0, 2.4], "size": [0.2, 0.3, 0.08]}
    world = make_world("small", seed=1, disturbances=[toy])
    nao = api_at(world, "nao", (1.2, 2.4, 0))
    assert await _walk(nao, 1.5)
    changes = (await nao.get_contacts(GetContacts(after=0))).changes
    assert changes and all(c.kind == "bumper" and c.pressed for c in changes[:1])


async def test_touch_sensors_are_pressed_for_a_time_and_validated(small):
    nao = api_at(small, "nao", (1.0, 2.4, 0))
    await small.touch("nao", "head_middle", seconds=0.5)
    now = await nao.get_contacts(GetContacts(after=0))
    assert now.pressed["head_middle"] and [(c.sensor, c.kind, c.pressed) for c in now.changes] == [
        ("head_middle", "touch", True)]
    await small.sleep(0.4)
    assert (await nao.get_contacts(GetContacts(after=now.last))).changes == []
    await small.sleep(0.2)
    later = await nao.get_contacts(GetContacts(after=now.last))
    assert [(c.sensor, c.pressed) for c in later.changes] == [("head_middle", False)]
    assert abs(later.changes[0].stamp - now.changes[0].stamp - 0.5) < 0.02  # simulation time
    with pytest.raises(InvalidArgument, match="no touch sensor 'nose'"):
        await small.touch("nao", "nose")
    with pytest.raises(InvalidArgument, match="positive"):
        await small.touch("nao", "hand_left", seconds=0)
    el = api_at(small, "elektron", (2.2, 0.5, 90))
    with pytest.raises(InvalidArgument):
        await small.touch("elektron", "head_front")
    with pytest.raises(UnsupportedOperation):
        await el.get_contacts(GetContacts())


async def test_a_scenario_file_touches_a_robot_on_its_timeline(make_world, caplog):
    pats = [{"kind": "touch", "robot": "nao", "sensor": "hand_left", "at": 0.5, "seconds": 0.3},
            {"kind": "touch", "robot": "elektron", "sensor": "head_front", "at": 0.2}]  # no robot of that name
    world = make_world("small", seed=1, disturbances=pats)
    nao = api_at(world, "nao", (1.0, 2.4, 0))
    await world.sleep(0.4)
    assert (await nao.get_contacts(GetContacts(after=0))).changes == []
    assert "touch 'touch-elektron-head_front-1' at 0.2 s not made: no robot 'elektron'" in caplog.text
    await world.sleep(0.2)  # pressed at 0.5 s, for 0.3 s
    now = await nao.get_contacts(GetContacts(after=0))
    assert [(c.sensor, c.kind, c.pressed) for c in now.changes] == [("hand_left", "touch", True)]
    assert abs(now.changes[0].stamp - 0.5) < 0.02
    await world.sleep(0.4)
    assert [(c.sensor, c.pressed) for c in (await nao.get_contacts(GetContacts(after=now.last))).changes] == [
        ("hand_left", False)]


def test_a_touch_of_a_sensor_no_body_has_is_refused_at_load():
    from robots.disturbances import DisturbanceError, load_disturbances

    with pytest.raises(DisturbanceError, match="no robot body has a touch sensor 'nose'"):
        load_disturbances([{"kind": "touch", "robot": "nao", "sensor": "nose", "at": 1}])
