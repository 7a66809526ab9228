"""Light of a time of day (robots/lighting.py): windows in the outside walls that glow by day and are
dark at night, rooms lit by the sky, lamps of several strengths; seeded; off by default."""
from __future__ import annotations

import math
import random

import numpy as np
import pytest

from ontology.robot import LookAtPoint, SetCameraParams
from robots import RobotAPI
from robots.lighting import Daylight, lamp_radiance, room_light, sky_level, with_daylight
from robots.floorplan import load_plan
from robots.world import HOUSES


def test_the_sky_follows_the_hour_and_the_cloud():
    assert sky_level(2.0, 0.0) == 0.0 and sky_level(21.0, 0.0) == 0.0
    assert sky_level(13.0, 0.0) > sky_level(8.0, 0.0) > 0.0
    assert sky_level(13.0, 1.0) < sky_level(13.0, 0.0)
    assert room_light(None) == 1.0 and room_light(0.0) < room_light(0.5) < room_light(1.0) == 1.0


def test_windows_stand_in_outside_walls_clear_of_codes_and_doorways():
    plan = load_plan(HOUSES / "house.yaml", seed=1)
    lit, info = with_daylight(plan, Daylight(seed=4, hour=11.0))
    assert lit.windows and info["windows"] == len(lit.windows) and lit.sky > 0 and lit.sky == pytest.approx(info["sky"], abs=1e-3)
    x0, y0, x1, y1 = plan.bounds
    t = plan.wall_thickness
    for w in lit.windows:
        on_outside = min(abs(w.x - x0), abs(w.x - x1), abs(w.y - y0), abs(w.y - y1)) <= t
        assert on_outside, w
        # both ends and the middle are in a wall (no door gap), no QR label beside it
        ux, uy = math.cos(w.yaw), math.sin(w.yaw)
        for k in (-0.5, 0.0, 0.5):
            px, py = w.x + ux * k * w.sx, w.y + uy * k * w.sx
            assert any(b.distance(px, py) < 1e-3 for b in plan.walls), (w.name, k)
        for m in plan.landmarks:
            along = abs((m.x - w.x) * ux + (m.y - w.y) * uy)
            across = abs((m.x - w.x) * uy - (m.y - w.y) * ux)
            assert across > 2 * t or along > w.sx / 2 + m.size / 2, (w.name, m.id)
    # the map's own plan is untouched: the studio light, every lamp at full strength
    assert plan.sky is None and not plan.windows and {lp.strength for lp in plan.lamps} == {1.0}


def test_drawn_from_the_seed():
    plan = load_plan(HOUSES / "house.yaml", seed=1)
    a, b = (with_daylight(plan, Daylight(seed=9))[1] for _ in range(2))
    c = with_daylight(plan, Daylight(seed=10))[1]
    assert a == b and a != c and 6.0 <= a["hour"] <= 23.0
    strengths = list(a["lamp_strength"].values())
    assert len(set(strengths)) > 1 and all(0.3 <= s <= 1.0 for s in strengths)


async def _window_and_lamp(make_world, hour: float | None):
    """Mean radiance-driven pixel values of the living room's south window and of a lit lamp."""
    world = make_world("house", seed=1, render="inline", overrides={"lamps": {"l_living": True}},
                       daylight=None if hour is None else Daylight(seed=1, hour=hour))
    api = RobotAPI(world.add_robot("nao", pose=(4.0, 2.5, -math.pi / 2)))
    await api.look_at_point(LookAtPoint(x=4.0, y=0.0, z=1.4))
    await api.set_camera_params(SetCameraParams(exposure=0.2, auto_exposure=False))
    frame = await api.capture_array(resolution="320x240")
    return float(frame[100:130, 140:180].mean()), float(frame[200:, :].mean()), world


async def test_a_window_glows_by_day_and_is_dark_at_night(make_world):
    noon, floor_noon, _ = await _window_and_lamp(make_world, 12.5)
    night, floor_night, _ = await _window_and_lamp(make_world, 23.5)
    studio, floor_studio, _ = await _window_and_lamp(make_world, None)
    assert noon > 3 * max(night, 1.0), (noon, night)
    assert floor_night < floor_noon  # the rooms darker without the sky
    # without daylight there is no window: the wall as it always was
    assert abs(studio - floor_studio) < abs(noon - floor_noon)


def test_a_dim_lamp_glows_less():
    assert np.all(np.array(lamp_radiance(0.3)) < np.array(lamp_radiance(1.0)))


@pytest.mark.parametrize("robot", ["nao"])
async def test_light_checks_hold_by_day_and_at_night(robot):
    """The hazard RApp's light check, lamps on and off, a random generated house at a day and a night
    hour: the answer is the switch, whatever the sky does (scenarios/light_validation.py at scale)."""
    from scenarios.hazard_validation import rapp_params
    from scenarios.light_validation import hours_for, lamp_checks

    seed = random.SystemRandom().randrange(1, 100_000)
    rows = []
    for hour in hours_for(random.Random(seed), 0):
        rows += await lamp_checks("generated", seed, robot, hour, rapp_params(), np.random.default_rng(seed))
    assert rows and {r.on for r in rows} == {True, False}
    wrong = [(r.lamp, r.on, r.level, r.strength, r.hour) for r in rows if not r.right]
    assert not wrong, f"house seed {seed}: {wrong}"


def test_the_scenarios_knob():
    import argparse

    from scenarios.hazard import realism, time_of_day

    assert realism("none", 5)["daylight"] is None  # the studio light unless asked
    assert realism("full", 5)["daylight"] == Daylight(seed=5, hour=None)  # drawn from the run's seed
    assert realism("full", 5)["mechanical_drive"] and not realism("none", 5)["mechanical_drive"]
    assert realism("none", 5, daylight="18:30")["daylight"] == Daylight(seed=5, hour=18.5)
    assert time_of_day("7.25") == 7.25 and time_of_day("random") is None
    for bad in ("25:00", "noon", "-1"):
        with pytest.raises(argparse.ArgumentTypeError, match="--daylight"):
            time_of_day(bad)


@pytest.mark.parametrize("render", ["inline", "process"])
async def test_the_worlds_room_light_dims_both_renderers(make_world, render):
    """World.light_scale (a validation's dim or bright room) reaches the frames rendered in the World's
    thread and in its render processes alike; it changes only what the room's light lights."""
    world = make_world("house", seed=1, render=render)
    api = RobotAPI(world.add_robot("nao", pose=(4.0, 2.5, -math.pi / 2)))
    await api.look_at_point(LookAtPoint(x=4.0, y=0.0, z=0.6))
    await api.set_camera_params(SetCameraParams(exposure=0.5, auto_exposure=False))
    levels = {}
    for scale in (1.0, 0.5, 1.0):
        world.light_scale = scale
        levels.setdefault(scale, []).append(float((await api.capture_array(resolution="160x120")).mean()))
    assert levels[0.5][0] < 0.8 * levels[1.0][0], levels
    assert levels[1.0][1] == pytest.approx(levels[1.0][0], rel=0.05)  # and back: nothing left changed
