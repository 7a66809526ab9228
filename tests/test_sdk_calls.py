"""The SDK's typed calls (rapps/sdk/calls.py) are generated from the ontology and stay in step."""
from __future__ import annotations

import inspect

import pytest

import rapps.sdk as sdk
from ontology.platform import ServiceRequest
from ontology.registry import ContentError, actions
from ontology.services.common import Pose2D
from rapps.sdk import generate


class Recorder:
    """Stands in for the Dynamic Agent's `request` (the transport is tested elsewhere)."""

    def __init__(self):
        self.sent = []

    async def request(self, to, content, timeout, on_feedback=None):
        self.sent.append((to, content, timeout))
        return content


def test_calls_py_is_what_the_generator_writes():
    assert generate.OUT.read_text() == generate.source(), "run: python -m rapps.sdk.generate"


def test_every_robot_action_and_platform_service_has_a_typed_method():
    robot = {n for n, f in vars(sdk.RobotCalls).items() if inspect.iscoroutinefunction(f)}
    platform = {n for n, f in vars(sdk.PlatformCalls).items() if inspect.iscoroutinefunction(f)}
    assert robot == set(actions("robot"))
    assert platform == {n for n, m in actions("platform").items() if issubclass(m, ServiceRequest)}
    sig = inspect.signature(sdk.PlatformCalls.path_planning_plan_path_2d)
    assert sig.parameters["token"].default is sdk.calls.UNSET  # added by the proxy unless given
    assert sig.parameters["start"].annotation == "Pose2D"
    assert sig.return_annotation == "PlanPathReply"


async def test_typed_calls_build_the_request_models_with_models_or_dicts():
    agent = Recorder()
    platform = sdk.PlatformProxy(agent, "platform@localhost", "tok")
    await platform.path_planning_plan_path_2d(robot_type="nao", map_id="m", start=Pose2D(x=0, y=0, theta=0),
                                              goal={"x": 1, "y": 2, "theta": 0}, _timeout=5)
    to, req, timeout = agent.sent[-1]
    assert (to, timeout, req.token, req.goal) == ("platform@localhost", 5, "tok", Pose2D(x=1, y=2, theta=0))
    assert req.algorithm == "astar"  # a default left UNSET is the model's own
    robot = sdk.RobotProxy(agent, "core@localhost")
    await robot.move_to(x=0.5)
    assert agent.sent[-1][1].model_dump() == {"x": 0.5, "y": 0.0, "theta": 0.0}
    with pytest.raises(ContentError, match="unknown action 'fly'"):
        await robot.fly(x=1)
    with pytest.raises(ValueError):  # the model still validates
        await robot.move_to(x="far")
