"""The SDK's hazard checks (rapps/sdk/checks.py) on a simulated robot in the small house: the door
check's geometry built from the robot's camera and the home's door, the light check's low exposure
restored afterwards; answers scored against the world's truth."""
from __future__ import annotations

import asyncio

import pytest

import rapps.sdk as sdk
from agents.services import ServiceContext, ServiceState, run_service
from ontology.robot import CameraInfo, Transform
from ontology.services.home import DoorShape, HazardSpec
from robots import RobotAPI, World
from scenarios.home_setup import doorway, lamp_hazard


class InProcess:
    """The Dynamic Agent's `request` without the transport (tested elsewhere): robot actions go to
    the simulated robot's RobotAPI, services to their implementation, as the Core and Platform run them."""

    def __init__(self, api):
        self.api, self.state, self.sent = api, ServiceState(), []

    async def request(self, to, content, timeout, on_feedback=None):
        self.sent.append(content)
        if content.ontology_name == "robot":
            return await self.api.handle(content)
        ctx = ServiceContext(user="owner", state=self.state)
        return await asyncio.to_thread(run_service, content.action_name, content, ctx)


def task_of(api):
    agent = InProcess(api)
    task = type("T", (), {})()
    task.robot, task.platform = sdk.RobotProxy(agent, "core@localhost"), sdk.PlatformProxy(agent, "p@localhost", "t")
    return task, agent


def test_door_geometry_is_the_camera_and_the_doors_shape():
    info = CameraInfo(camera="top", width=640, height=480, K=[[500, 0, 319.5], [0, 510, 239.5], [0, 0, 1]],
                      P=[[500, 0, 319.5, 0], [0, 510, 239.5, 0], [0, 0, 1, 0]], hfov_deg=65, vfov_deg=50)
    pose = Transform(chain="camera", space="global", matrix=[[1, 0, 0, 2], [0, 1, 0, 1], [0, 0, 1, 1], [0, 0, 0, 1]])
    g = sdk.door_geometry(info, pose, DoorShape(hinge=[3.5, 1.0], closed_yaw_deg=90, width_m=0.9))
    assert (g.camera.fx, g.camera.fy, g.camera.cx, g.camera.cy) == (500, 510, 319.5, 239.5)
    assert g.camera_to_world == pose.matrix and (g.hinge, g.closed_yaw_deg, g.width_m) == ([3.5, 1.0], 90, 0.9)
    with pytest.raises(ValueError, match="global frame"):
        sdk.door_geometry(info, pose.model_copy(update={"space": "robot"}), DoorShape(hinge=[0, 0], closed_yaw_deg=0))
    lamp = HazardSpec(id="l1", type="lamp", stand={"x": 1, "y": 1}, look_at=[0.4, 3.6, 1.4])
    with pytest.raises(ValueError, match="'l1' is not a door"):
        sdk.door_geometry(info, pose, lamp)


async def test_check_door_and_check_light_from_the_homes_check_poses():
    """A NAO checks the door from the doorway's front check pose, closed and 50 degrees open; an
    Elektron checks the lamp on and off."""
    with World.from_file("small", seed=1, overrides={"doors": {"d1": 0.0}, "lamps": {"l1": True}},
                         render="inline") as world:
        d1 = doorway(world.plan, world.plan.doors[0])
        stand = d1.check_from("front").stand
        api = RobotAPI(world.add_robot("nao", pose=(stand.x, stand.y, stand.theta)))
        task, agent = task_of(api)
        answers = {}
        for angle in (0.0, 50.0):
            await world.set_door("d1", angle)
            answers[angle] = await sdk.check_door(task, d1)
        assert answers[0.0].method == "geometry" and answers[0.0].door_angle < 10.0, answers
        assert abs(answers[50.0].door_angle - 50.0) < 12.0, answers
        request = next(c for c in agent.sent if c.action_name == "hazard_detection_door_check")
        assert request.geometry.hinge == [3.5, 1.0] and request.method == "geometry"
        look = next(c for c in agent.sent if c.action_name == "look_at_point")
        assert [look.x, look.y, look.z] == d1.check_from("front").look_at  # the nearer check pose's point

        lamp = lamp_hazard(world.plan.lamps[0], (1.0, -1.0))  # the small house's lamp hazard
        task, agent = task_of(RobotAPI(world.add_robot("elektron", pose=(lamp.stand.x, lamp.stand.y, lamp.stand.theta))))
        exposure = (await task.robot.set_camera_params()).exposure
        on = await sdk.check_light(task, lamp)
        await world.set_lamp("l1", False)
        off = await sdk.check_light(task, lamp)
        assert (on.lamp_on, off.lamp_on) == (True, False), (on, off)
        assert (await task.robot.set_camera_params()).exposure == exposure  # restored
        assert any(c.action_name == "set_camera_params" and c.exposure == sdk.checks.LIGHT_EXPOSURE for c in agent.sent)
