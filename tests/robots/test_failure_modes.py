"""The robots' failure modes (robots/failure_modes.py): slip moves the TRUE pose away from the odometry by a
bounded amount, the same seed gives the same run, the NAO's body sways while it walks, cameras are noisy
and blur while moving, an exposure the RApp sets turns auto-exposure off, range sensors are noisy, and
the switch gives ideal robots."""
import asyncio
import math

import numpy as np
import pytest

from ontology.robot import GetGlobalPose, MoveJoint, MoveTo, SetCameraParams
from ontology.robot_types import ROBOT_TYPES
from robots.bodies import ROBOT_SPECS
from robots.failure_modes import (NAO_SONAR, CameraNoise, ideal_robots, noisy_ranges)
from robots.odometry import wrap
from robots.receptors import ImageParams, apply_params

from .conftest import api_at

START = {"nao": (1.0, 2.4, 0), "elektron": (1.0, 2.4, 0)}  # 'small': 1.5 m free ahead


def world(make_world, seed=1):
    return make_world("small", seed=seed, overrides={"doors": {"d1": 0}, "lamps": {"l1": True}}, render="inline")


async def walk(api, x=1.5, theta=0.0):
    await api.move_to(MoveTo(x=x, y=0.0, theta=theta))
    est = await api.get_global_pose(GetGlobalPose())
    return (est.x, est.y, est.theta), api.robot.pose


@pytest.mark.parametrize("kind", ["nao", "elektron"])
async def test_slip_moves_the_truth_off_the_odometry_by_a_bounded_amount(make_world, kind):
    w = world(make_world)
    api = api_at(w, kind, START[kind])
    est, truth = await walk(api)
    # the odometry reports the commanded motion: 1.5 m straight ahead
    assert math.hypot(est[0] - 2.5, est[1] - 2.4) < 0.01 and abs(est[2]) < 0.01
    d, a = math.hypot(truth[0] - est[0], truth[1] - est[1]), abs(wrap(truth[2] - est[2]))
    assert d > 0.003  # slip is there (1 % short at least)
    bound = {"nao": (0.25, 0.3), "elektron": (0.06, 0.05)}[kind]  # ~4 sigma after 1.5 m
    assert d < bound[0] and a < bound[1], (d, a)


async def test_elektron_slips_more_on_turns(make_world):
    w = world(make_world)
    api = api_at(w, "elektron", START["elektron"])
    await api.move_to(MoveTo(x=0.0, y=0.0, theta=math.pi))  # half a turn on the spot
    est = await api.get_global_pose(GetGlobalPose())
    turn_err = abs(wrap(api.robot.pose[2] - est.theta))
    assert 0.01 < turn_err < 0.25  # 2 % of pi short plus noise
    assert math.hypot(api.robot.pose[0] - est.x, api.robot.pose[1] - est.y) < 1e-9  # no translation on the spot


async def test_same_seed_same_run_other_seed_other_run(make_world):
    runs = []
    for seed in (1, 1, 2):
        api = api_at(world(make_world, seed), "nao", START["nao"])
        runs.append((await walk(api, 1.0, 0.5))[1])
    assert runs[0] == runs[1]
    assert runs[0] != runs[2]


async def test_nao_sways_while_walking_and_settles(make_world):
    w = world(make_world)
    api = api_at(w, "nao", START["nao"])
    ys = []

    async def sample():
        for _ in range(40):
            await w.sleep(0.1)
            ys.append(api.robot.pose[1])

    await asyncio.gather(api.move_to(MoveTo(x=1.4, y=0.0, theta=0.0)), sample())
    side = np.array(ys[5:25]) - np.polyval(np.polyfit(np.arange(20), ys[5:25], 1), np.arange(20))
    assert 0.01 < np.abs(side).max() < 0.03  # +-2 cm sway about the walking line
    assert api.robot.locomotion.offset == 0.0  # at rest over its feet


async def test_ideal_switch_makes_truth_equal_odometry(make_world, monkeypatch):
    w = world(make_world)
    with ideal_robots():
        api = api_at(w, "nao", START["nao"])
    est, truth = await walk(api, 1.0, 0.5)
    assert math.hypot(truth[0] - est[0], truth[1] - est[1]) < 1e-9 and abs(wrap(truth[2] - est[2])) < 1e-9
    assert api.robot.cameras["top"].params == ImageParams()  # manual exposure, no noise
    other = api_at(w, "elektron", (2.2, 0.5, 90))
    other.robot.set_failure_modes(None)  # one robot made ideal after it was added
    est, truth = await walk(other, 0.5, 1.0)
    assert math.hypot(truth[0] - est[0], truth[1] - est[1]) < 1e-9
    monkeypatch.setenv("RAPP_FAILURE_MODES", "off")
    assert api_at(w, "elektron", (1.0, 1.0, 0), name="e2").robot.locomotion is None


async def test_camera_noise_is_present_and_seeded(make_world):
    w = world(make_world)
    api = api_at(w, "nao", (1.6, 2.2, 120))
    a = await api.capture_array(resolution="160x120")
    b = await api.capture_array(resolution="160x120")  # same simulation step: the same noise
    await w.sleep(0.1)
    c = await api.capture_array(resolution="160x120")
    assert np.array_equal(a, b)
    diff = np.abs(a.astype(int) - c.astype(int))
    assert diff.mean() > 0.3 and diff.max() < 40  # noise of a few grey levels, not a different image
    api.robot.set_failure_modes(None)
    await w.sleep(0.1)
    d = await api.capture_array(resolution="160x120")
    await w.sleep(0.1)
    assert np.array_equal(d, await api.capture_array(resolution="160x120"))


async def test_exposure_set_by_the_rapp_turns_auto_exposure_off(make_world):
    w = world(make_world)
    api = api_at(w, "nao", (1.6, 2.2, 120))
    saved = await api.set_camera_params(SetCameraParams())
    assert saved.auto_exposure  # a real camera starts with auto-exposure
    auto = await api.capture_array(resolution="160x120")
    reply = await api.set_camera_params(SetCameraParams(exposure=0.2))  # as the light check does
    assert not reply.auto_exposure and reply.exposure == 0.2
    dark = await api.capture_array(resolution="160x120")
    assert dark.mean() < auto.mean() - 30
    restored = await api.set_camera_params(SetCameraParams(exposure=saved.exposure, auto_exposure=True))
    assert restored.auto_exposure
    assert abs((await api.capture_array(resolution="160x120")).mean() - auto.mean()) < 3


async def test_head_motion_blurs_the_image(make_world):
    w = world(make_world)
    api = api_at(w, "elektron", (2.2, 1.4, 120))
    cam = api.robot.cameras["head"]
    assert cam.params.blur_rate == (0.0, 0.0)
    motion = asyncio.ensure_future(api.move_joint(MoveJoint(joints=["HeadPan"], angles=[2.0], speed=1.0)))
    await w.sleep(0.3)
    rate = cam.params.blur_rate
    await motion
    assert abs(rate[0]) == pytest.approx(api.robot.spec.joint_speed, rel=0.01) and rate[1] == 0.0
    # the same radiance: blurred (fewer sharp edges) while the head moves
    rng = np.random.default_rng(0)
    scene = np.repeat(np.kron(rng.random((12, 16)), np.ones((10, 10)))[:, :, None], 3, 2).astype(np.float32)
    still = apply_params(scene, ImageParams())
    moving = apply_params(scene, ImageParams(blur_rate=rate, exposure_time_s=0.03, hfov_rad=math.radians(45)))
    def edges(img):  # gradient energy along the image rows (where the pan smears the image)
        return float((np.diff(img.astype(float), axis=1) ** 2).mean())

    assert edges(moving) < 0.3 * edges(still)


def test_range_noise_is_bounded_and_keeps_no_echo():
    rng = np.random.default_rng(0)
    exact = np.array([0.5, 1.0, 2.0, 2.55])
    noisy = np.array([noisy_ranges(exact, NAO_SONAR, rng, 0.25, 2.55) for _ in range(500)])
    assert noisy[:, 3].tolist() == [2.55] * 500  # no echo stays no echo
    err = noisy[:, :3] - exact[:3]
    assert 0.005 < err.std() < 0.02 and np.abs(err).max() < 0.06
    assert np.allclose(noisy, np.round(noisy, 2))  # 1 cm resolution


async def test_sonar_and_laser_readings_are_noisy(make_world):
    w = world(make_world)
    nao = api_at(w, "nao", START["nao"]).robot
    elektron = api_at(w, "elektron", (2.2, 1.4, 120)).robot
    exact = w.run_sync(lambda: elektron.laser.scan(noisy=False))
    noisy = w.run_sync(elektron.laser.scan)
    hit = exact < elektron.laser.spec.range_max
    assert np.abs(noisy - exact)[hit].mean() > 0.002 and np.abs(noisy - exact)[hit].max() < 0.2
    sonar = nao.sonars[0]
    assert abs(w.run_sync(sonar.read) - w.run_sync(lambda: sonar.scan(noisy=False).min())) < 0.06


def test_every_robot_kind_has_failure_modes():
    assert all(ROBOT_SPECS[kind].failures is not None for kind in ROBOT_TYPES)
    nao = ROBOT_SPECS["nao"].failures
    assert nao.camera == CameraNoise() and nao.walk.sway_amplitude_m == 0.02


async def _walk_sampled(api, world, seconds: float) -> list[tuple[float, float]]:
    """Walk straight ahead at a steady command and sample the true (x, y) every world step."""
    from ontology.robot import MoveVel

    samples = []
    await api.move_vel(MoveVel(x=0.06, y=0.0, theta=0.0))
    end = world.time + seconds
    while world.time < end:
        await world.sleep(world.clock.step)
        samples.append(api.robot.pose[:2])
    await api.move_vel(MoveVel(x=0.0, y=0.0, theta=0.0))
    return samples


async def test_the_mechanical_nao_moves_by_steps_with_the_same_mean_walk(make_world):
    from robots.failure_modes import mechanical

    ends, speeds = {}, {}
    for steps in (False, True):
        w = world(make_world)
        api = api_at(w, "nao", START["nao"])
        if steps:
            api.robot.set_failure_modes(mechanical(api.robot.failure_modes))
        samples = await _walk_sampled(api, w, 3.0)  # six steps of 0.5 s
        v = np.diff(np.array(samples)[:, 0]) / w.clock.step
        ends[steps], speeds[steps] = samples[-1], v[30:]  # past the first step's start
    # by steps: the body stops in double support and runs at about twice the mean mid-step
    assert speeds[True].min() < 0.2 * 0.06 and speeds[True].max() > 1.6 * 0.06, (speeds[True].min(), speeds[True].max())
    assert speeds[False].min() > 0.5 * 0.06  # the glide never stops
    # whole steps: where it gets to is the glide's (the same slip drawn per step)
    assert math.dist(ends[True], ends[False]) < 0.01, (ends[True], ends[False])


async def test_the_mechanical_elektron_turns_short_and_veers_from_its_wheel_sides(make_world):
    from robots.failure_modes import mechanical

    w = world(make_world)
    api = api_at(w, "elektron", START["elektron"])
    api.robot.set_failure_modes(mechanical(api.robot.failure_modes))
    assert api.robot.locomotion.wheels.differential
    await api.move_to(MoveTo(x=0.0, y=0.0, theta=math.pi / 2))
    est = await api.get_global_pose(GetGlobalPose())
    short = wrap(est.theta - api.robot.pose[2])  # the odometry counted the whole turn
    assert 0.01 < short < 0.08, short  # ~2 % of a quarter turn short, the skid wandering about it
    # on the spot, the sides slipping apart move the centre a little (mm)
    assert math.hypot(api.robot.pose[0] - est.x, api.robot.pose[1] - est.y) < 0.005
    # straight ahead, the sides slip apart: a heading error grows, with no random kick per step
    before = api.robot.pose
    est0 = await api.get_global_pose(GetGlobalPose())
    await api.move_to(MoveTo(x=1.2, y=0.0, theta=0.0))
    est1 = await api.get_global_pose(GetGlobalPose())
    veer = abs(wrap((api.robot.pose[2] - before[2]) - (est1.theta - est0.theta)))
    assert 1e-5 < veer < 0.05, veer
