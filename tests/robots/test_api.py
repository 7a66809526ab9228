"""Robot API surface: one request model per method, typed errors, speech, postures, sensors."""
import asyncio
import math

import numpy as np
import pytest

from ontology.registry import Done, actions, decode_request
from ontology.robot import (ROBOT_ACTIONS, GetJointAngles, GetLaserScan, GetSonars, GetTransform, MoveJoint,
                            MoveTo, Rest, Say, TakePredefinedPosture, WordSpotting)
from robots import InvalidArgument, RobotAPI, UnsupportedOperation

from .conftest import api_at


def test_every_action_has_a_method_and_a_group():
    # every robot action is served by the robot API; the Core serves the resource locks and its pose
    # estimate itself
    assert set(actions("robot")) - set(ROBOT_ACTIONS) == {"lock_resource", "free_resource", "get_pose_estimate",
                                                          "add_pose_fix"}
    for name, model in ROBOT_ACTIONS.items():
        assert callable(getattr(RobotAPI, name)), name
        assert model.group in {"communication", "vision", "navigation", "sensors"}
        assert model.reply_model is not None


async def test_generic_dispatch_from_json(small):
    api = api_at(small, "nao", (1.0, 2.4, 0))
    req = decode_request("robot", "move_to", '{"x": 0.2, "y": 0.0, "theta": 0.0}')
    reply = await api.handle(req)
    assert isinstance(reply, Done) and abs(small.ground_truth().robots["nao"][0] - 1.2) < 0.01


async def test_say_on_nao_and_unsupported_on_elektron(small):
    nao = api_at(small, "nao", (1.0, 2.4, 0))
    el = api_at(small, "elektron", (2.2, 0.5, 90))
    t0 = small.time
    await nao.say(Say(text="the door is open"))
    assert nao.robot.loudspeaker.spoken[-1][1] == "the door is open" and small.time > t0
    with pytest.raises(UnsupportedOperation, match="speech"):
        await el.say(Say(text="hello"))
    with pytest.raises(UnsupportedOperation):
        await nao.get_laser_scan(GetLaserScan())
    with pytest.raises(UnsupportedOperation):
        await el.get_sonars(GetSonars())


async def test_word_spotting(small):
    nao = api_at(small, "nao", (1.0, 2.4, 0))
    task = asyncio.create_task(nao.word_spotting(WordSpotting(words=["hazard", "news"], timeout=2.0)))
    await asyncio.sleep(0.01)
    nao.robot.microphone.hear("something else")
    nao.robot.microphone.hear("start the Hazard detection")
    got = await task
    assert got.word == "hazard" and "Hazard" in got.text
    none = await nao.word_spotting(WordSpotting(words=["x"], timeout=0.05))
    assert none.word is None


async def test_postures_and_joints(small):
    nao = api_at(small, "nao", (1.0, 2.4, 0))
    cam_stand = np.array((await nao.get_transform(GetTransform(chain="camera"))).matrix)
    await nao.take_predefined_posture(TakePredefinedPosture(posture="Crouch", speed=1.0))
    cam_crouch = np.array((await nao.get_transform(GetTransform(chain="camera"))).matrix)
    assert cam_crouch[2, 3] < cam_stand[2, 3] - 0.05  # the head went down with the legs
    await nao.move_joint(MoveJoint(joints=["HeadYaw"], angles=[0.5], speed=0.5))
    q = await nao.get_joint_angles(GetJointAngles(joints=["HeadYaw"]))
    assert q.angles == [pytest.approx(0.5)]
    with pytest.raises(InvalidArgument, match="unknown joint"):
        await nao.move_joint(MoveJoint(joints=["Tail"], angles=[0.0]))
    with pytest.raises(InvalidArgument, match="unknown posture"):
        await nao.take_predefined_posture(TakePredefinedPosture(posture="Handstand"))
    await nao.rest(Rest())
    el = api_at(small, "elektron", (2.2, 0.5, 90))
    await el.move_joint(MoveJoint(joints=["HeadPan", "HeadTilt"], angles=[0.3, 5.0]))
    q = await el.get_joint_angles(GetJointAngles())
    assert dict(zip(q.joints, q.angles)) == {"HeadPan": pytest.approx(0.3), "HeadTilt": pytest.approx(1.1)}


async def test_range_sensors(small):
    el = api_at(small, "elektron", (2.2, 2.0, 0))  # facing the inner wall at x = 3.45
    scan = await el.get_laser_scan(GetLaserScan())
    mid = scan.ranges[len(scan.ranges) // 2]
    assert mid == pytest.approx(3.45 - (2.2 + 0.16), abs=0.02)
    nao = api_at(small, "nao", (2.8, 3.0, 0))
    son = await nao.get_sonars(GetSonars())
    assert 0.25 <= min(son.left, son.right) < 0.8


async def test_new_base_command_preempts_the_old_one(small):
    from robots import MotionInterrupted
    el = api_at(small, "elektron", (2.2, 0.5, 90))
    first = asyncio.create_task(el.move_to(MoveTo(x=2.0)))
    await small.sleep(1.0)
    await el.move_to(MoveTo(x=0.0, theta=math.pi / 2))
    with pytest.raises(MotionInterrupted):
        await first
