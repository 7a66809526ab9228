"""Base motion: closed squares, path following, odometry drift, kinematic limits, walls."""
import asyncio
import math

import pytest

from ontology.robot import GetGlobalPose, MoveAlongPath, MoveStop, MoveTo, MoveVel, Pose2D, SetGlobalPose
from robots import MotionBlocked, OdometryNoise, UnsupportedOperation
from robots.odometry import wrap
from scenarios.recorder import RecordingAPI

from .conftest import api_at

POS_TOL, ANG_TOL = 0.05, math.radians(5)


@pytest.fixture(autouse=True)
def ideal_robots(monkeypatch):
    """These tests check the motion controllers and the odometry model exactly: ideal robots, without
    the walk's slip and sway or the wheels' slip (tests/robots/test_failure_modes.py tests those)."""
    monkeypatch.setenv("RAPP_FAILURE_MODES", "off")


def err(a, b):
    return math.hypot(a[0] - b[0], a[1] - b[1]), abs(wrap(a[2] - b[2]))


@pytest.mark.parametrize("kind,start,turn", [("nao", (1.0, 2.4, 0), 1), ("elektron", (2.2, 0.5, 90), -1)])
async def test_square_with_move_to_returns_to_start(small, kind, start, turn):
    api = api_at(small, kind, start)
    start_truth = small.ground_truth().robots[kind]
    t0 = small.time
    for _ in range(4):
        await api.move_to(MoveTo(x=0.8, y=0.0, theta=turn * math.pi / 2))
    d, a = err(small.ground_truth().robots[kind], start_truth)
    assert d < POS_TOL and a < ANG_TOL, (d, math.degrees(a))
    # motions take simulation time: 3.2 m at the robot's top speed at least
    assert small.time - t0 >= 3.2 / api.robot.spec.max_vx


@pytest.mark.parametrize("kind,start,corners", [
    ("nao", (1.0, 2.4, 0), [(0.8, 0), (0.8, 0.8), (0, 0.8)]),
    ("elektron", (2.2, 0.5, 90), [(0, 0.8), (0.8, 0.8), (0.8, 0)]),
])
async def test_square_with_path_follower_returns_to_start(small, kind, start, corners):
    api = api_at(small, kind, start)
    x, y, th = small.ground_truth().robots[kind]
    path = [Pose2D(x=x, y=y, theta=th)] + [Pose2D(x=x + dx, y=y + dy, theta=th) for dx, dy in corners] + \
        [Pose2D(x=x, y=y, theta=th)]
    recorder = RecordingAPI(api)  # samples the true trajectory every 0.1 s of simulation
    await recorder.handle(MoveAlongPath(poses=path))
    d, a = err(small.ground_truth().robots[kind], (x, y, th))
    assert d < POS_TOL and a < ANG_TOL, (d, math.degrees(a))
    assert small.time > 3.0 / api.robot.spec.max_vx  # it really went round
    # the corners are followed, not cut (a cut corner is a door frame hit)
    assert recorder.tracking_error() < 0.04, recorder.tracking_error()


async def test_odometry_drift_visible_with_noise_and_corrected_by_set_global_pose(small):
    api = api_at(small, "nao", (1.0, 2.4, 0), odometry_noise=OdometryNoise.typical())
    for _ in range(4):
        await api.move_to(MoveTo(x=0.8, y=0.0, theta=math.pi / 2))
    est = await api.get_global_pose(GetGlobalPose())
    truth = small.ground_truth().robots["nao"]
    d, a = err((est.x, est.y, est.theta), truth)
    assert d > 0.03 or a > math.radians(3), (d, math.degrees(a))
    await api.set_global_pose(SetGlobalPose(x=truth[0], y=truth[1], theta=truth[2]))
    est = await api.get_global_pose(GetGlobalPose())
    assert err((est.x, est.y, est.theta), truth)[0] < 1e-9


async def test_no_noise_estimate_equals_truth(small):
    api = api_at(small, "elektron", (2.2, 0.5, 90))
    await api.move_to(MoveTo(x=0.5, y=0.3, theta=1.0))
    est = await api.get_global_pose(GetGlobalPose())
    d, a = err((est.x, est.y, est.theta), small.ground_truth().robots["elektron"])
    assert d < 1e-6 and a < 1e-6


async def test_diff_drive_refuses_lateral_velocity(small):
    api = api_at(small, "elektron", (2.2, 0.5, 90))
    with pytest.raises(UnsupportedOperation, match="(?i)lateral.*differential|differential.*lateral"):
        await api.move_vel(MoveVel(x=0.1, y=0.1, theta=0.0))


async def test_holonomic_nao_moves_sideways(small):
    api = api_at(small, "nao", (1.0, 2.4, 0))
    await api.move_to(MoveTo(x=0.0, y=0.3, theta=0.0))
    x, y, th = small.ground_truth().robots["nao"]
    assert abs(x - 1.0) < 0.01 and abs(y - 2.7) < 0.01 and abs(th) < 0.01


async def test_move_vel_runs_in_sim_time_until_stop(small):
    api = api_at(small, "elektron", (2.2, 0.5, 90))
    await api.move_vel(MoveVel(x=0.2, theta=0.0))
    await small.sleep(2.0)
    await api.move_stop(MoveStop())
    y1 = small.ground_truth().robots["elektron"][1]
    assert y1 - 0.5 == pytest.approx(0.4, abs=0.02)
    await small.sleep(1.0)
    assert small.ground_truth().robots["elektron"][1] == y1


@pytest.mark.parametrize("kind", ["nao", "elektron"])
async def test_wall_stops_the_robot(small, kind):
    # inner wall at x = 3.5 (thickness 0.1), the door is at y 1.0..1.9: drive east at y = 3.0
    api = api_at(small, kind, (2.8, 3.0, 0))
    with pytest.raises(MotionBlocked):
        await api.move_to(MoveTo(x=1.5, y=0.0, theta=0.0))
    x = small.ground_truth().robots[kind][0]
    assert x < 3.45 - api.robot.spec.radius + 0.01


async def test_robots_collide_with_each_other(small):
    a = api_at(small, "elektron", (1.8, 0.5, 0))
    api_at(small, "nao", (2.8, 0.5, 0))
    with pytest.raises(MotionBlocked):
        await a.move_to(MoveTo(x=1.0))
    assert small.ground_truth().robots["elektron"][0] < 2.8 - 0.17 - 0.26 + 0.01


async def test_concurrent_motions_advance_together(small):
    import asyncio
    n = api_at(small, "nao", (1.0, 2.4, 0))
    e = api_at(small, "elektron", (2.2, 0.5, 90))
    t0 = small.time
    await asyncio.gather(n.move_to(MoveTo(x=0.6)), e.move_to(MoveTo(x=1.0)))
    # concurrent: total sim time is the longer motion, not the sum
    assert small.time - t0 < 0.6 / 0.12 + 2.0


async def test_moving_forward_is_what_the_safety_monitor_watches(small):
    """Turning on the spot next to a wall must not look like driving at it (the Core's safety monitor
    reads the sonars only while the base moves forward)."""
    api = api_at(small, "nao", (1.0, 2.4, 0))
    assert not api.moving_forward()  # standing
    turn = asyncio.create_task(api.move_to(MoveTo(x=0.0, theta=math.pi)))
    await small.sleep(0.3)
    assert not turn.done() and not api.moving_forward()
    await turn
    await api.move_vel(MoveVel(x=0.1))
    await small.sleep(0.3)
    assert api.moving_forward()
    await api.move_stop(MoveStop())
    assert not api.moving_forward()
