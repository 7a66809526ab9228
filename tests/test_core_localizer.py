"""The Core's own pose estimate (agents/core_localizer.py, paper 001): the odometry followed by the pose EKF,
fused with the fixes a RApp sends (add_pose_fix), served with its covariance (get_pose_estimate) through the
Core's command server; a RApp's set_global_pose resets the odometry without moving the estimate."""
import asyncio
import math
from types import SimpleNamespace

import numpy as np

from agents.core_commands import RobotCommands
from agents.core_localizer import CoreLocalizer
from ontology.robot import AddPoseFix, GetGlobalPose, GetPoseEstimate, MoveTo, SetGlobalPose
from ontology.robot_actions import ROBOT_API_GROUPS

LEGS = [(1.2, math.pi / 2), (1.0, math.pi / 2), (1.2, math.pi / 2), (1.0, math.pi / 2)] * 2  # twice round a rectangle


def _err(pose, truth) -> float:
    return math.hypot(pose[0] - truth[0], pose[1] - truth[1])


async def test_fixes_make_the_cores_estimate_better_than_odometry_and_shrink_its_covariance():
    from robots import OdometryNoise, RobotAPI, World

    rng = np.random.default_rng()  # the fixes' noise, drawn at run time
    world = World.from_file("small", seed=int(rng.integers(1000)), render="inline")
    try:
        api = RobotAPI(world.add_robot("nao", pose=(0.9, 1.9, 0.0), odometry_noise=OdometryNoise.typical()))
        loc = CoreLocalizer(api, "nao")
        loc.start()
        first = await loc.handle(GetPoseEstimate())
        assert first.fixes == 0 and math.isclose(first.std_m, 0.5) and np.allclose(first.covariance, np.diag([0.25, 0.25, 0.09]))
        shrunk = []
        for i, (ahead, turn) in enumerate(LEGS):
            await api.move_to(MoveTo(x=ahead, theta=turn))
            await asyncio.sleep(0.15)  # a sample of the odometry between legs, at least
            if i % 3 == 2 or i == len(LEGS) - 1:  # a QR fix every third leg and at the end: the truth with 3 cm / 2 deg of noise
                x, y, th = world.ground_truth().robots["nao"]
                before = await loc.handle(GetPoseEstimate())
                # within 2 sigma of the truth: the 99 % gate refuses 1 in 100 honest fixes, which the
                # test would take for a filter too sure of itself (it failed so once in the suite)
                dx, dy, dth = np.clip(rng.normal(0, 1, 3), -2, 2) * (0.03, 0.03, 0.035)
                fix = await loc.handle(AddPoseFix(x=x + dx, y=y + dy, theta=th + dth, std_m=0.03, std_rad=0.035))
                assert fix.accepted and fix.fixes == before.fixes + 1
                shrunk.append((np.trace(np.asarray(before.covariance)[:2, :2]), np.trace(np.asarray(fix.covariance)[:2, :2])))
        await api.move_to(MoveTo(x=0.5))
        truth = world.ground_truth().robots["nao"]
        odometry = await api.get_global_pose(GetGlobalPose())
        core = await loc.handle(GetPoseEstimate())
        assert all(after < before / 2 for before, after in shrunk), shrunk
        e_core, e_odo = _err((core.pose.x, core.pose.y), truth), _err((odometry.x, odometry.y), truth)
        assert e_core < e_odo and e_core < 0.12, (e_core, e_odo)
        assert e_core < 3 * core.std_m + 0.03  # its covariance says how far off it may be
        wrong = await loc.handle(AddPoseFix(x=truth[0] + 2.0, y=truth[1], theta=truth[2], std_m=0.03, std_rad=0.03))
        assert not wrong.accepted and wrong.fixes == core.fixes  # 2 m off: refused by the gate
        await loc.stop()
    finally:
        world.close()


async def test_set_global_pose_resets_the_odometry_not_the_estimate_and_the_command_server_serves_it():
    from robots import RobotAPI, World

    world = World.from_file("small", seed=1, render="inline")
    try:
        api = RobotAPI(world.add_robot("elektron", pose=(1.0, 2.4, 0.0)))
        core, ctx = _stand_in_core(api)  # the Core's command server, with the localizer the Core gives it
        core.localizer = CoreLocalizer(api, "elektron")
        await core._robot_call(AddPoseFix(x=1.0, y=2.4, theta=0.0, std_m=0.02, std_rad=0.02), ctx)
        await api.move_to(MoveTo(x=0.5))
        await core._robot_call(SetGlobalPose(x=5.0, y=1.0, theta=1.0), ctx)  # a RApp's own (wrong) pose
        assert (await api.get_global_pose(GetGlobalPose())).x == 5.0  # the robot's odometry was set ...
        await api.move_to(MoveTo(x=0.4))
        est = await core._robot_call(GetPoseEstimate(), ctx)
        assert abs(est.pose.x - 1.9) < 0.03 and abs(est.pose.y - 2.4) < 0.03  # ... the Core's estimate followed the motion
        assert est.fixes == 1 and 0.02 < est.std_m < 0.1
    finally:
        world.close()



def _stand_in_core(api):
    """The Core's command server on a stand-in Core (what RobotCommands needs of its host), and the
    requester's context of a Dynamic Agent holding every group of the robot API."""
    async def nothing(*a, **k):
        return None

    host = SimpleNamespace(robot=api, robot_id="el-1", record_structure=lambda *a, **k: None, address="core@x",
                           tracer=None, tell_user=nothing, notify=nothing, in_background=lambda coro: coro.close(),
                           dynamic=SimpleNamespace(jid="dyn@x/r", rapp="r", ended=asyncio.Event(),
                                                   manifest=SimpleNamespace(robot_api=sorted(ROBOT_API_GROUPS))))
    ctx = SimpleNamespace(sender="dyn@x", wants_feedback=False, feedback=None,
                          info=SimpleNamespace(conversation_id="c-1"))
    return RobotCommands(host, publish=nothing), ctx


async def test_a_read_that_spans_several_legs_is_as_uncertain_as_the_legs():
    """The Core reads the odometry every 0.1 s of wall clock: in a world run much faster than real time one
    read spans several legs. The uncertainty grows with the motion the odometry counted between reads
    (RobotInterface.odometry_counters), not with the displacement, which is nothing once round a loop (it
    grew too little: a filter too sure of itself refused honest fixes); and the command server reads as
    each leg starts and ends, so a task's legs are predicted one by one whatever the wall clock caught."""
    from robots import OdometryNoise, RobotAPI, World

    world = World.from_file("small", seed=1, render="inline")
    try:
        api = RobotAPI(world.add_robot("nao", pose=(0.9, 1.9, 0.0), odometry_noise=OdometryNoise.typical()))
        core, ctx = _stand_in_core(api)
        # none started (no wall-clock reads): the first reads when asked after each leg, the second once at
        # the end, the third as the command server serves the legs
        each_leg, once, served = CoreLocalizer(api, "nao"), CoreLocalizer(api, "nao"), CoreLocalizer(api, "nao")
        core.localizer = served
        for loc in (each_leg, once, served):  # all start from the same sure fix
            await loc.handle(AddPoseFix(x=0.9, y=1.9, theta=0.0, std_m=0.01, std_rad=0.01))
        start = np.trace(np.asarray((await once.handle(GetPoseEstimate())).covariance)[:2, :2])
        for ahead, turn in LEGS[:4]:  # once round the rectangle, back where it started
            await core._robot_call(MoveTo(x=ahead, theta=turn), ctx)
            await each_leg.handle(GetPoseEstimate())
        covs = [np.asarray((await loc.handle(GetPoseEstimate())).covariance) for loc in (each_leg, once, served)]
        grown = [np.trace(c[:2, :2]) - start for c in covs]
        assert grown[0] > 0 and grown[1] > 0.5 * grown[0], grown  # one read for 4.4 m: at least half as unsure
        assert np.allclose(covs[2], covs[0]), covs  # the served legs: each on its own
    finally:
        world.close()
