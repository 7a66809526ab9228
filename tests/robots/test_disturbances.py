"""Things that move in the house (robots/disturbances.py): people walking routes, doors swung on a schedule,
dropped boxes; seen by the robots' rays and cameras, counted when a robot touches them. Physics only."""
import math

import numpy as np
import pybullet as p
import pytest

from ontology.robot import GetLaserScan, GetSonars, MoveTo
from robots import InvalidArgument, MotionBlocked, World
from robots.disturbances import DisturbanceError, Disturbances, DroppedBox, Route, load_disturbances
from robots.floorplan import load_plan
from robots.world import HOUSES

from .conftest import api_at


def person(route, **kw):
    return {"kind": "person", "id": kw.pop("id", "p1"), "route": route, **kw}


def mover(world, ident):
    return world.ground_truth().movers.get(ident)


async def ahead(api) -> float:
    """The laser's range straight ahead: the median of the five middle rays (1 deg apart; ranges are noisy)."""
    ranges = (await api.get_laser_scan(GetLaserScan())).ranges
    mid = len(ranges) // 2
    return float(np.median(ranges[mid - 2:mid + 3]))


def bluish(image) -> np.ndarray:
    """Pixels of the person's blue clothes (walls, floor and furniture are not blue)."""
    img = image.astype(int)
    return img[:, :, 2] > img[:, :, 0] + 30


async def sleep_until(world, t):
    await world.sleep(t - world.time)


# ------------------------------------------------------------------------------------------ timelines
def test_route_walks_pauses_and_loops():
    # 2 m east, 1 m north with a 2 s stop at the corner, at 0.5 m/s from t = 1
    r = Route([(0.0, 0.0, 0.0), (2.0, 0.0, 2.0), (2.0, 1.0, 0.0)], speed=0.5, start=1.0, loop=False)
    assert r.at(0.5)[:2] == (0.0, 0.0)  # waits at the first point until its start
    assert r.at(3.0)[:2] == pytest.approx((1.0, 0.0))
    assert r.at(6.0)[:2] == pytest.approx((2.0, 0.0)) and r.at(6.9)[:2] == pytest.approx((2.0, 0.0))  # stop
    assert r.at(8.0)[:2] == pytest.approx((2.0, 0.5)) and r.at(8.0)[2] == pytest.approx(math.pi / 2)
    assert r.at(100.0)[:2] == pytest.approx((2.0, 1.0))  # stays at the end
    loop = Route([(0.0, 0.0, 1.0), (3.0, 0.0, 0.0), (3.0, 4.0, 0.0)], speed=1.0, start=0.0, loop=True)
    assert loop.period == pytest.approx(1 + 3 + 4 + 5)  # the pause at the start, three legs back to it
    assert loop.at(10.5)[:2] == pytest.approx((3.0 - 0.6 * 2.5, 4.0 - 0.8 * 2.5))  # on the way back
    assert loop.at(13.5)[:2] == pytest.approx((0.0, 0.0))  # waiting at the start of round two
    assert loop.at(13.0 + 2.0)[:2] == pytest.approx((1.0, 0.0))


def test_a_dropped_box_falls_freely_to_the_floor():
    spec = load_disturbances([{"kind": "box", "id": "b", "at": 2.0, "position": [1, 1], "size": [0.2, 0.2, 0.2],
                               "drop_height": 1.0}])
    box = DroppedBox(spec.disturbances[0], np.random.default_rng(0))
    assert box.pose_at(1.99) is None
    assert box.pose_at(2.2)[2] == pytest.approx(0.1 + 1.0 - 9.81 / 2 * 0.04)
    assert box.pose_at(2.0 + math.sqrt(2 / 9.81) + 0.01)[2] == pytest.approx(0.1)


# ------------------------------------------------------------------------------------------ in a world
async def test_person_walks_the_route_on_time(make_world):
    world = make_world("small", render="inline", disturbances=[
        person([[0.5, 3.0], [3.0, 3.0], {"x": 3.0, "y": 2.0, "pause": 2}, [2.0, 2.0]], speed=0.5, start=1.0)])
    assert mover(world, "p1")[:2] == (0.5, 3.0)
    expected = {0.5: (0.5, 3.0), 3.0: (1.5, 3.0), 7.0: (3.0, 2.5), 9.5: (3.0, 2.0), 11.0: (2.5, 2.0),
                20.0: (2.0, 2.0)}
    for t, (x, y) in expected.items():
        await sleep_until(world, t)
        got = mover(world, "p1")
        assert math.hypot(got[0] - x, got[1] - y) < 0.01, (t, got)
    # the body itself is there (what rays and renders see), standing on the floor
    uid = next(m.uid for m in world.disturbances.movers)
    pos, _ = world.run_sync(p.getBasePositionAndOrientation, uid, physicsClientId=world.cid)
    assert pos == pytest.approx((2.0, 2.0, 0.85), abs=0.01)


@pytest.mark.parametrize("render", ["process", "inline"])
async def test_a_person_in_front_is_seen_by_laser_sonar_and_camera(make_world, render):
    # the person walks north at x = 2 past an Elektron (y = 2) and a NAO (y = 3), both facing east
    world = make_world("small", render=render, disturbances=[person([[2.0, 1.2], [2.0, 3.7]], speed=1.0,
                                                                    start=0.5)])
    el = api_at(world, "elektron", (0.5, 2.0, 0))
    nao = api_at(world, "nao", (0.5, 3.0, 0))
    wall = await ahead(el)
    sonar_before = await nao.get_sonars(GetSonars())
    image_before = await el.capture_array()
    assert wall == pytest.approx(3.45 - 0.66, abs=0.08)  # the inner wall behind the person's path
    assert sonar_before.right == sonar_before.range_max  # nothing in the right sonar's cone

    await sleep_until(world, 1.3)  # the person is at (2.0, 2.0): right in front of the Elektron
    assert await ahead(el) == pytest.approx(2.0 - 0.175 - 0.66, abs=0.05)
    image = await el.capture_array()
    h, w, _ = image.shape
    centre = (slice(h // 2 - 5, h // 2 + 5), slice(w // 2 - 5, w // 2 + 5))
    assert bluish(image)[centre].all() and not bluish(image_before)[centre].any()  # in the middle of the picture now

    await sleep_until(world, 2.0)  # at (2.0, 2.7): front right of the NAO, past the Elektron
    sonar = await nao.get_sonars(GetSonars())
    assert 1.2 < sonar.right < 1.45, sonar  # the person's near side, ~1.3 m off the sonar
    assert await ahead(el) == pytest.approx(wall, abs=0.08)


async def test_camera_image_of_a_person_is_the_same_from_the_render_process(make_world):
    spec = [person([[2.0, 2.0]], id="standing")]
    masks = []
    for render in ("process", "inline"):
        world = make_world("small", render=render, disturbances=spec)
        masks.append(bluish(await api_at(world, "elektron", (0.5, 2.0, 0)).capture_array()))
    assert masks[0].sum() > 0.05 * masks[0].size  # the person fills a good part of the picture
    assert (masks[0] != masks[1]).mean() < 0.005  # at the same place in both (edge pixels may differ)


async def test_a_door_closes_on_schedule(make_world):
    world = make_world("small", overrides={"doors": {"d1": 90}}, render="inline",
                       disturbances=[{"kind": "door", "door": "d1", "at": 1.0, "angle": 0, "duration": 2.0}])
    door = world.plan.doors[0]

    def joint_deg():
        return math.degrees(world.run_sync(p.getJointState, world.door_uids["d1"], 0,
                                           physicsClientId=world.cid)[0]) * door.sign

    for t, angle in ((0.5, 90.0), (2.0, 45.0), (3.5, 0.0)):
        await sleep_until(world, t)
        assert world.ground_truth().doors["d1"] == pytest.approx(angle, abs=1.0), t
        assert joint_deg() == pytest.approx(angle, abs=1.0), t


async def test_a_dropped_box_appears_at_its_time(make_world):
    world = make_world("small", render="inline", disturbances=[
        {"kind": "box", "id": "toy", "at": 1.0, "position": [2.0, 2.0], "size": [0.3, 0.3, 0.3]}])
    el = api_at(world, "elektron", (0.5, 2.0, 0))
    await sleep_until(world, 0.9)
    assert mover(world, "toy") is None
    assert await ahead(el) > 2.5
    await sleep_until(world, 1.1)
    assert mover(world, "toy") == pytest.approx((2.0, 2.0, 0.0))
    assert await ahead(el) == pytest.approx(2.0 - 0.15 - 0.66, abs=0.05)


async def test_a_person_walking_into_a_standing_robot_is_one_contact_per_episode(make_world):
    # back and forth through a NAO standing at (2, 2): two touching episodes, each counted once
    # (a person who does not yield: `yields: false`)
    world = make_world("small", render="inline", disturbances=[
        person([[0.6, 2.0], [3.2, 2.0]], speed=1.0, start=0.5, loop=True, yields=False)])
    api_at(world, "nao", (2.0, 2.0, 0))
    await sleep_until(world, 3.1)  # the first pass is over
    assert world.person_contacts() == 1 and world.object_contacts() == 0
    first = world.contact_events()[0]
    assert (first.robot, first.other, first.kind) == ("nao", "p1", "person")
    assert first.time == pytest.approx(0.5 + 2.0 - 0.17 - 0.175 - 0.6, abs=0.05)  # when the surfaces meet
    await sleep_until(world, 4.5)  # on its way back it walks through the robot again
    assert world.person_contacts() == 2 and world.person_contacts("nao") == 2 and world.person_contacts("x") == 0


async def test_a_person_waits_for_a_robot_in_the_way_then_walks_on(make_world):
    # the same walk with a yielding person (the default): they stop short of the NAO and never touch it;
    # once the NAO has gone, they walk on (their route runs late by the wait)
    world = make_world("small", render="inline", disturbances=[
        person([[0.6, 2.0], [3.2, 2.0]], speed=1.0, start=0.5)])
    api_at(world, "nao", (2.0, 2.0, 0))
    await sleep_until(world, 4.0)
    x, y, _ = world.disturbances.poses()["p1"]
    gap = 2.0 - x - 0.175 - world.robots["nao"].spec.radius
    assert 0.15 < gap <= 0.3 and world.person_contacts() == 0
    await world.run(world.robots["nao"].set_base_pose, 2.0, 0.6, 0.0)  # the robot steps aside
    await sleep_until(world, 7.0)
    assert world.disturbances.poses()["p1"][0] == pytest.approx(3.2, abs=0.01) and world.person_contacts() == 0


async def test_a_robot_driving_into_a_dropped_box_is_blocked_and_counted(make_world):
    world = make_world("small", render="inline", disturbances=[
        {"kind": "box", "id": "toy", "at": 0.0, "position": [2.0, 2.0], "size": [0.3, 0.3, 0.3]}])
    el = api_at(world, "elektron", (1.0, 2.0, 0))
    with pytest.raises(MotionBlocked):
        await el.move_to(MoveTo(x=1.5, y=0.0, theta=0.0))
    assert world.ground_truth().robots["elektron"][0] == pytest.approx(2.0 - 0.15 - 0.26, abs=0.02)
    assert world.object_contacts() == 1 and world.person_contacts() == 0


async def test_same_seed_same_disturbances(make_world):
    spec = [person([[0.5, 3.0], [3.0, 3.0], [3.0, 2.0]], speed=[0.4, 1.2], start=[0, 2]),
            {"kind": "box", "id": "toy", "at": [0.5, 2.5], "position": [2.0, 2.0], "size": [0.2, 0.2, 0.2]}]
    runs = []
    for seed in (7, 7, 8):
        world = make_world("small", seed=seed, render="inline", disturbances=spec)
        trace = []
        for _ in range(6):
            await world.sleep(0.5)
            trace.append(dict(world.ground_truth().movers))
        runs.append(trace)
        walker = world.disturbances.movers[0]
        assert 0.4 <= walker.speed <= 1.2 and 0 <= walker.start <= 2
    assert runs[0] == runs[1]
    assert runs[0] != runs[2]


async def test_the_example_file_runs_in_its_house(make_world):
    world = make_world("small", seed=1, render="inline", disturbances="small-disturbances")
    await sleep_until(world, 30.0)
    truth = world.ground_truth()
    assert truth.doors["d1"] == 0.0  # opened for the visitor, closed after
    assert truth.movers["visitor"][:2] == pytest.approx((4.6, 1.45)) and truth.movers["toy"][:2] == (2.0, 2.0)


# ------------------------------------------------------------------------------------------ bad specs
@pytest.mark.parametrize("entries,words", [
    ([person([[1, 1]], speed=-0.5)], ["speed", "> 0"]),
    ([person([[1, 1]], speed=[1.0, 0.5])], ["speed", "low end"]),
    ([person([[1, 1]], speed=9)], ["at most 3 m/s"]),
    ([person([])], ["route", "at least 1"]),
    ([person([[1, 1, 2, 3]])], ["[x, y] or [x, y, pause]"]),
    ([{"kind": "door", "door": "d1", "at": -1, "angle": 0}], ["at", ">= 0"]),
    ([{"kind": "door", "door": "d1", "angle": 0}], ["at", "Field required"]),
    ([{"kind": "cat", "id": "c"}], ["'cat'", "person", "door", "box"]),
    ([person([[1, 1]]), person([[2, 2]])], ["two disturbances have the id 'p1'"]),
    ([{"kind": "box", "id": "b", "at": 1, "position": [1, 1], "size": [0.2, 0, 0.2]}], ["size", "greater than 0"]),
    ([person([[1, 1]], sped=1)], ["sped", "Extra inputs"]),
])
def test_a_bad_spec_is_a_clear_error(entries, words):
    with pytest.raises(DisturbanceError) as err:
        load_disturbances(entries)
    for w in words:
        assert w in str(err.value), str(err.value)


@pytest.mark.parametrize("entries,words", [
    ([{"kind": "door", "door": "front", "at": 1, "angle": 0}], ["unknown door 'front'", "house 'small'", "d1"]),
    ([person([[1, 1], [9, 1]])], ["(9, 1) is outside house 'small'"]),
    ([{"kind": "door", "id": "open", "door": "d1", "at": 1, "angle": 90, "duration": 2},
      {"kind": "door", "id": "shut", "door": "d1", "at": 2, "angle": 0}], ["'shut' starts at 2 s, before 'open'"]),
])
def test_a_spec_that_does_not_fit_the_house_is_a_clear_error(entries, words):
    with pytest.raises(DisturbanceError) as err:
        Disturbances(load_disturbances(entries), load_plan(HOUSES / "small.yaml", seed=1))
    for w in words:
        assert w in str(err.value), str(err.value)


def test_a_bad_file_is_a_clear_error_and_builds_no_world(tmp_path):
    with pytest.raises(DisturbanceError, match="cannot read disturbance file"):
        World.from_file("small", render="inline", disturbances=tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("disturbances:\n  - {kind: door, door: dx, at: 1, angle: 0}\n")
    with pytest.raises(DisturbanceError, match=r"disturbances\[0\] \(door 'door-dx-0'\): unknown door 'dx'"):
        World.from_file("small", render="inline", disturbances=bad)
    with World.from_file("small", render="inline", disturbances=[]) as world, \
            pytest.raises(InvalidArgument, match="already"):
        world.attach_disturbances([])
