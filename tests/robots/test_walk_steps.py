"""The NAO walking by steps (issue 48.5, `--mechanical-drive`): its torso rolls toward the stance foot and
bobs at the step frequency, and its camera sees from there while the robot's own kinematics
(get_transform) stay the nominal ones; a walk stopped mid-step finishes the step, an emergency stop
included, and still stops clear of what it was stopped for. With the knob off (the default) everything
is bit for bit what it was before this was built."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ontology.robot import GetGlobalPose, GetTransform, LookAtPoint, MoveStop, MoveTo, MoveVel
from robots import MotionBlocked
from robots.failure_modes import mechanical

from .conftest import api_at

START = (1.0, 2.4, 0)  # 'small': 1.5 m free ahead
STEP_S = 0.5
BOX = {"kind": "box", "id": "crate", "at": 0.0, "position": [2.0, 2.0], "size": [0.3, 0.6, 0.8]}


def small(make_world, **kw):
    return make_world("small", seed=1, overrides={"doors": {"d1": 0}, "lamps": {"l1": True}}, render="inline", **kw)


def by_steps(api):
    api.robot.set_failure_modes(mechanical(api.robot.failure_modes))
    assert api.robot.locomotion.walk.steps
    return api


def roll_deg(T: np.ndarray) -> float:
    """The optical frame's roll: its x axis (image right) out of the horizontal, deg."""
    return math.degrees(math.asin(float(T[2, 0])))


# ---------------------------------------------------------------------------- knob off: unchanged
# Measured on 1944532 (the commit this was built on), before the roll, bob and finishing step existed:
# the scripted motions below with the default drive gave exactly these values
GOLDEN = {
    "nao": dict(
        pose=(1.6533145295034541, 2.517818506663534, 0.4343825232886216),
        est=(1.6539382596292618, 2.5261488337039437, 0.47776988809055565),
        tf=(1.7220987231961573, 2.49950616273545, 0.503795862197876),
        mid=(1.711280107498169, 2.544710874557495, 0.5139209628105164),
        blur=(0.11040846957941572, 0.0), time=7.416666666666646, travelled=0.6681234651647081),
    "elektron": dict(
        pose=(1.646380607969589, 1.6255503397256619, 0.47577715161399636),
        est=(1.6538564212556852, 1.6265261796697057, 0.4763598235932127),
        tf=(1.595096529834311, 1.585622867766989, 1.044622540473938),
        mid=(1.5894886255264282, 1.5962364673614502, 1.0700000524520874),
        blur=(0.1, 0.0), time=14.416666666666963, travelled=0.6597651270416168),
}


async def test_the_default_drive_is_bit_for_bit_what_it_was(make_world):
    """The lead's hazard tables run with the default drive: a walk, a turn, a stop mid-step and a look,
    for both robots in one world, give the same poses, odometry, camera poses and motion blur to the
    last bit as before the mechanical drive's roll, bob and finishing step were built."""
    w = small(make_world)
    got = {}
    for kind in ("nao", "elektron"):
        api = api_at(w, kind, (1.0, 2.4 if kind == "nao" else 1.6, 0))
        await api.move_to(MoveTo(x=0.6, y=0.1 if kind == "nao" else 0.0, theta=0.4))
        await api.move_vel(MoveVel(x=0.08, y=0.0, theta=0.1))
        await w.sleep(0.77)
        cam = api.robot.cameras[api.robot.spec.look_camera]
        mid, blur = w.run_sync(cam.optical_pose), cam.params.blur_rate
        await api.move_stop(MoveStop())
        await w.sleep(0.4)
        await api.look_at_point(LookAtPoint(x=3.0, y=2.0, z=0.3))
        est = await api.get_global_pose(GetGlobalPose())
        tf = np.asarray((await api.get_transform(GetTransform(chain="camera", space="global"))).matrix)
        got[kind] = dict(pose=tuple(float(v) for v in api.robot.pose), est=(est.x, est.y, est.theta),
                         tf=tuple(float(v) for v in tf[:3, 3]), mid=tuple(float(v) for v in mid[:3, 3]),
                         blur=tuple(float(v) for v in blur), time=w.time, travelled=api.robot.odometry.travelled)
        # upright: the camera is where the kinematics put it
        assert np.array_equal(w.run_sync(cam.optical_pose), w.run_sync(cam.optical_pose, True))
    assert got == GOLDEN


# ---------------------------------------------------------------------------- the head rolls and bobs
async def test_the_head_rolls_and_bobs_with_the_steps_and_the_robot_does_not_know(make_world):
    w = small(make_world)
    api = by_steps(api_at(w, "nao", START))
    r, cam = api.robot, api.robot.cameras["top"]
    await api.move_vel(MoveVel(x=0.1, y=0.0, theta=0.0))
    await w.sleep(1.0)  # the sway builds up over the first steps
    samples = []
    for _ in range(int(2 * 2 * STEP_S / w.clock.step)):  # two sway cycles (four steps)
        await w.sleep(w.clock.step)
        true, nominal = w.run_sync(cam.optical_pose), w.run_sync(cam.optical_pose, True)
        samples.append((roll_deg(true), true[2, 3] - nominal[2, 3], r.locomotion.offset,
                        r.locomotion.step_left, float(np.linalg.norm(true[:3, 3] - nominal[:3, 3]))))
    roll, dz, offset, step_left, shift = map(np.array, zip(*samples))
    assert 1.5 < roll.max() < 2.5 and -2.5 < roll.min() < -1.5, (roll.min(), roll.max())  # +-2 deg
    assert 2.0 < 1000 * dz.max() < 3.5 and -3.5 < 1000 * dz.min() < -2.0, (dz.min(), dz.max())  # +-3 mm
    # toward the stance foot: rolled to the side the body swayed to
    far = np.abs(offset) > 0.01
    assert far.sum() > 20 and np.all(np.sign(roll[far]) == np.sign(offset[far]))
    # bobbing once a step: lowest mid-step (one leg carries it), highest in double support
    mid_step = np.abs(step_left - STEP_S / 2) < 0.05
    double_support = (step_left < 0.04) | (step_left > STEP_S - 0.04)
    assert dz[mid_step].max() < -0.002 and dz[double_support].min() > 0.002
    assert shift.max() > 0.005  # the camera swings a centimetre sideways with the roll

    # the render's view is the true pose (the eye and the image's up), the robot reports the nominal one
    view, _ = w.run_sync(cam.view_projection, 64, 48)
    cam_from_view = np.linalg.inv(np.asarray(view).reshape(4, 4).T)  # OpenGL camera: x right, y up, z back
    true = w.run_sync(cam.optical_pose)
    assert np.allclose(cam_from_view[:3, 3], true[:3, 3], atol=1e-5)
    assert np.allclose(cam_from_view[:3, 0], true[:3, 0], atol=1e-5)  # image right, rolled
    tf = np.asarray((await api.get_transform(GetTransform(chain="camera", space="robot"))).matrix)
    nominal_in_base = w.run_sync(lambda: r.in_base(cam.optical_pose(nominal=True)))
    assert np.allclose(tf, nominal_in_base, atol=1e-12)
    assert abs(roll_deg(tf)) < 1e-6  # upright, as far as the robot knows
    # the motion blur has the bob's vertical rate in it (the head is still, the walk straight)
    vertical = []
    for _ in range(8):
        await w.sleep(w.clock.step)
        vertical.append(abs(cam.params.blur_rate[1]))
    assert max(vertical) > 1e-3, vertical
    await api.move_stop(MoveStop())


async def test_without_the_knob_the_head_stays_upright(make_world):
    w = small(make_world)
    api = api_at(w, "nao", START)
    cam = api.robot.cameras["top"]
    await api.move_vel(MoveVel(x=0.1, y=0.0, theta=0.0))
    for _ in range(20):
        await w.sleep(0.05)
        assert api.robot.body_sway() is None
        assert abs(roll_deg(w.run_sync(cam.optical_pose))) < 1e-6
    await api.move_stop(MoveStop())


# ---------------------------------------------------------------------------- a stopped walk finishes its step
@pytest.mark.parametrize("stop", ["move_stop", "halt"])
async def test_a_walk_stopped_mid_step_finishes_the_step(make_world, stop):
    w = small(make_world)
    api = by_steps(api_at(w, "nao", START))
    r = api.robot
    v = 0.1
    await api.move_vel(MoveVel(x=v, y=0.0, theta=0.0))
    await w.sleep(1.75)  # three steps and a half
    left = r.locomotion.step_left
    assert 0.2 < left < 0.3
    t0, est0, x0 = w.time, r.odometry.estimate, r.pose[0]
    if stop == "move_stop":
        await api.move_stop(MoveStop())
    else:
        await api.halt("an emergency stop")
    await w.sync()
    while r.locomotion.finishing():  # (the world steps the step to its end by itself)
        await w.sync()
    # the rest of the step, in simulated time: the walk engine reports it, the body walks it
    assert w.time - t0 == pytest.approx(left, abs=1.5 * w.clock.step)
    assert r.odometry.estimate[0] - est0[0] == pytest.approx(v * left, abs=0.002)
    assert r.pose[0] - x0 == pytest.approx(v * left, rel=0.3)
    # and comes to rest over its feet, upright
    assert r.locomotion.offset == 0.0 and r.body_sway() is None and not r.locomotion.finishing()
    t1 = w.time
    await w.sleep(0.2)
    assert r.odometry.estimate[0] == pytest.approx(est0[0] + v * left, abs=0.002) and w.time == pytest.approx(t1 + 0.2)


async def test_a_motion_commanded_after_a_stop_waits_for_the_step_to_land(make_world):
    """Backing off right after a stop mid-step: the step under way lands forward first (the world's
    steps done by hand here, so that the new command comes while the stopped step is under way)."""
    from robots.controllers import drive_base

    w = small(make_world)
    api = by_steps(api_at(w, "nao", START))
    r, dt = api.robot, w.clock.step
    await api.move_vel(MoveVel(x=0.1, y=0.0, theta=0.0))
    await w.sleep(1.75)  # (the unpaced world stops here, the walk mid-step)
    left, est0 = r.locomotion.step_left, r.odometry.estimate[0]

    def world_steps():
        r.locomotion.tick(r, dt)  # a world step that no motion drove: the stopped walk's step goes on
        moves = []
        for _ in range(int(0.5 / dt)):  # a newer motion backs off
            before = r.odometry.estimate[0]
            drive_base(r, -0.06, 0.0, 0.0, dt)
            r.locomotion.tick(r, dt)
            moves.append(r.odometry.estimate[0] - before)
        return moves

    moves = w.run_sync(world_steps)
    forward = [m for m in moves if m > 0]
    assert len(forward) == pytest.approx(left / dt - 1, abs=1.01) and moves[len(forward)] < 0, moves
    assert r.odometry.estimate[0] - est0 == pytest.approx(0.1 * left - 0.06 * (0.5 - left + dt), abs=0.002)
    await api.move_stop(MoveStop())


async def test_without_the_knob_a_stopped_walk_stops_dead(make_world):
    w = small(make_world)
    api = api_at(w, "nao", START)
    await api.move_vel(MoveVel(x=0.1, y=0.0, theta=0.0))
    await w.sleep(1.75)
    t0, est0 = w.time, api.robot.odometry.estimate
    await api.move_stop(MoveStop())
    assert w.time == t0 and api.robot.odometry.estimate == est0


async def test_a_motion_that_reaches_its_goal_lands_its_last_step_there(make_world):
    """moveTo plans its last step to land on the goal: no step is added after the goal is reached."""
    w = small(make_world)
    api = by_steps(api_at(w, "nao", START))
    await api.move_to(MoveTo(x=0.5, y=0.0, theta=0.0))
    t, est = w.time, api.robot.odometry.estimate
    assert math.hypot(est[0] - 1.5, est[1] - 2.4) < 0.004 and not api.robot.locomotion.finishing()
    await w.sleep(0.3)
    assert api.robot.odometry.estimate == est and w.time == pytest.approx(t + 0.3)


async def test_an_emergency_stop_finishes_the_step_and_still_keeps_clear_of_the_box(make_world):
    """The collision protection stops the walk; the step under way takes the body on by up to a step's
    length (6 cm at full speed), and the 0.10 m margin beyond the sonars' 0.25 m minimum range still
    keeps it clear of the box it was stopped for."""
    world = small(make_world, disturbances=[BOX])
    api = by_steps(api_at(world, "nao", (1.0, 2.0, 0)))
    r = api.robot
    api.protect(0.10)
    with pytest.raises(MotionBlocked, match="collision protection"):
        await api.move_to(MoveTo(x=1.5, y=0.0, theta=0.0))
    at_stop, est_at_stop, left = r.pose[0], r.odometry.estimate[0], r.locomotion.step_left
    assert left > 0.05  # stopped mid-step
    await world.sync()
    while r.locomotion.finishing():
        await world.sync()
    x = world.ground_truth().robots["nao"][0]
    # it walked on: the walk engine counts the rest of the step, the body walks it
    assert r.odometry.estimate[0] - est_at_stop > 0.005 and x > at_stop
    gap = 2.0 - 0.15 - (x + r.spec.radius)  # between the body and the box's near face
    assert 0.02 < gap and world.object_contacts() == 0, gap
    # the margin holds for the worst case too: a whole step at full speed from where it was stopped
    gap_at_stop = 2.0 - 0.15 - (at_stop + r.spec.radius)
    assert gap_at_stop - r.spec.max_vx * r.locomotion.walk.step_period_s > 0.02, gap_at_stop
