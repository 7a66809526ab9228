"""One row of facts per robot action (ontology/robot_actions.py), read by the Core's command server,
the locks and the requester's retries. The answers below were written down from the code before the
table existed (agents/locks.py ACTION_DEVICE, agents/core_commands.py MOTION_ACTIONS and its
"driving" cases, ontology/registry.py's name-based guess of idempotency): a changed answer fails."""
from __future__ import annotations

import asyncio
import importlib
import pkgutil
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

import ontology
from agents.base import RappAgent
from agents.core_commands import RobotCommands
from agents.errors import RequestTimeout
from agents.locks import DEVICES, ResourceLocks, device_of
from robots.errors import MotionBlocked
from ontology.manifest import ROBOT_API_GROUPS as MANIFEST_GROUPS
from ontology.registry import actions
from ontology.robot_actions import ACTION_FACTS, ROBOT_API_GROUPS, markdown_table

ROOT = Path(__file__).resolve().parents[1]
for _m in pkgutil.walk_packages(ontology.__path__, "ontology."):  # register every ontology's actions
    importlib.import_module(_m.name)

# ---------------------------------------------------------------- the answers before the table
OLD_GROUP = {
    "say": "communication", "word_spotting": "communication",
    # the audio part of the robot API (issue 19), added after the table was frozen
    "capture_audio": "communication", "play_audio": "communication", "microphone_energy": "communication",
    "capture_image": "vision", "set_camera_param": "vision", "set_camera_params": "vision",
    "get_camera_info": "vision",
    "move_to": "navigation", "move_vel": "navigation", "move_stop": "navigation",
    "move_along_path": "navigation", "look_at_point": "navigation", "get_global_pose": "navigation",
    "set_global_pose": "navigation", "get_transform": "navigation", "move_joint": "navigation",
    "get_joint_angles": "navigation", "take_predefined_posture": "navigation", "rest": "navigation",
    "get_sonars": "sensors", "get_laser_scan": "sensors",
    "lock_resource": "resources", "free_resource": "resources",
    # issue 47: the contact sensors, the depth camera and the Core's pose estimate, added after the freeze
    "get_contacts": "sensors", "capture_depth": "vision", "get_pose_estimate": "navigation",
    "add_pose_fix": "navigation",
}
CORE_SERVED = {"lock_resource", "free_resource", "get_pose_estimate", "add_pose_fix"}
OLD_DEVICE = {  # agents/locks.py ACTION_DEVICE; every other action: None
    "capture_audio": "microphone", "microphone_energy": "microphone", "play_audio": "speaker",
    "move_to": "base", "move_vel": "base", "move_along_path": "base",
    "look_at_point": "head", "move_joint": "joints", "take_predefined_posture": "joints",
    "rest": "joints", "capture_image": "camera", "set_camera_param": "camera",
    "set_camera_params": "camera", "say": "speaker", "word_spotting": "microphone",
}
OLD_MOTION = {"move_to", "move_vel", "move_along_path", "look_at_point", "move_joint",
              "take_predefined_posture", "rest"}
OLD_DRIVE_SETS = {"move_vel"}
OLD_DRIVE_ENDS = {"move_stop", "move_to", "move_along_path"}
OLD_DEVICES = ("base", "head", "joints", "camera", "speaker", "microphone")
# every registered action of every ontology, and whether it was idempotent (re-sent after a timeout);
# five pure reads were wrongly not (home_get_info, path_planning_list_maps, cognitive_get_history,
# interpret_command, object_detection_find_objects): corrected on purpose
OLD_IDEMPOTENT = {
    ("core", "get_state"): True, ("core", "heartbeat"): False, ("core", "report"): False,
    ("core", "task_status"): False,
    ("platform", "cloud_agent_down"): False, ("platform", "cloud_ready"): False,
    ("platform", "cognitive_get_history"): True, ("platform", "cognitive_record_performance"): False,
    ("platform", "cognitive_test_chooser"): False, ("platform", "compute_global_pose"): True,
    ("platform", "email_fetch"): False, ("platform", "email_send"): False,
    ("platform", "face_detection"): True, ("platform", "hazard_detection_door_check"): True,
    ("platform", "hazard_detection_light_check"): True, ("platform", "home_get_info"): True,
    ("platform", "home_upload_info"): False, ("platform", "human_detection"): True,
    ("platform", "interpret_command"): True, ("platform", "issue_app_token"): False,
    ("platform", "list_services"): True, ("platform", "login"): False,
    ("platform", "news_explore"): True, ("platform", "object_detection_clear_models"): False,
    ("platform", "object_detection_find_objects"): True, ("platform", "object_detection_learn_object"): False,
    ("platform", "ontology_is_subclass_of"): True, ("platform", "ontology_subclasses_of"): True,
    ("platform", "ontology_superclasses_of"): True, ("platform", "path_planning_list_maps"): True,
    ("platform", "path_planning_plan_path_2d"): True, ("platform", "path_planning_upload_map"): False,
    ("platform", "ping"): True, ("platform", "qr_detection"): True, ("platform", "register_robot"): False,
    ("platform", "register_user"): False, ("platform", "release_cloud_agents"): False,
    ("platform", "start_cloud_agent"): False, ("platform", "stop_cloud_agent"): False,
    ("platform", "verify_token"): False, ("platform", "weather_report_current"): True,
    ("platform", "weather_report_forecast"): True,
    ("robot", "capture_audio"): True, ("robot", "microphone_energy"): True, ("robot", "play_audio"): False,
    ("platform", "speech_recognition"): True, ("platform", "text_to_speech"): True,
    ("platform", "speech_noise_profile"): False,
    ("robot", "capture_image"): True, ("robot", "free_resource"): False, ("robot", "get_camera_info"): True,
    ("robot", "get_global_pose"): True, ("robot", "get_joint_angles"): True, ("robot", "get_laser_scan"): True,
    ("robot", "get_sonars"): True, ("robot", "get_transform"): True, ("robot", "lock_resource"): False,
    ("robot", "look_at_point"): False, ("robot", "move_along_path"): False, ("robot", "move_joint"): False,
    ("robot", "move_stop"): False, ("robot", "move_to"): False, ("robot", "move_vel"): False,
    ("robot", "rest"): False, ("robot", "say"): False, ("robot", "set_camera_param"): False,
    ("robot", "set_camera_params"): False, ("robot", "set_global_pose"): False,
    ("robot", "take_predefined_posture"): False, ("robot", "word_spotting"): False,
    ("robot", "get_contacts"): True, ("robot", "capture_depth"): True, ("robot", "get_pose_estimate"): True,
    ("robot", "add_pose_fix"): False,
    ("store", "catalogue_changed"): False, ("store", "delete"): False, ("store", "download_chunk"): True,
    ("store", "download_info"): True, ("store", "info"): True, ("store", "list_packages"): True,
    ("store", "publish"): False, ("store", "register_owner"): False, ("store", "register_robot"): False,
    ("store", "search"): True, ("store", "subscribe_catalogue"): False, ("store", "upload_chunk"): False,
    ("store", "versions"): True,
}

ROBOT = sorted(actions("robot"))


# ---------------------------------------------------------------- one row per action
def test_every_robot_action_has_exactly_one_row():
    assert sorted(ACTION_FACTS) == ROBOT == sorted(OLD_GROUP)
    for name, model in actions("robot").items():
        row = ACTION_FACTS[name]
        assert (model.group, model.idempotent) == (row.group, row.idempotent), name  # registered from its row
        assert row.device is None or row.device in DEVICES, name
        assert row.drive in (None, "sets", "ends"), name


def test_the_groups_and_devices_are_unchanged():
    assert {n: ACTION_FACTS[n].group for n in ROBOT} == OLD_GROUP
    assert DEVICES == OLD_DEVICES and tuple(ResourceLocks()._locks) == OLD_DEVICES
    # ontology/manifest.py keeps its own copy of the groups a manifest may declare: it must agree
    assert ROBOT_API_GROUPS == MANIFEST_GROUPS == {"communication", "vision", "navigation", "sensors"}


@pytest.mark.parametrize("name", ROBOT)
def test_locks_motion_and_driving_answer_as_before(name):
    row = ACTION_FACTS[name]
    assert device_of(name) == OLD_DEVICE.get(name)
    assert row.motion == (name in OLD_MOTION)
    assert row.drive == ("sets" if name in OLD_DRIVE_SETS else "ends" if name in OLD_DRIVE_ENDS else None)


def test_idempotency_answers_as_before_and_is_never_guessed():
    now = {key: model.idempotent for key, model in
           ((k, actions(k[0])[k[1]]) for k in OLD_IDEMPOTENT if k[1] in actions(k[0]))}
    assert now == OLD_IDEMPOTENT
    import ontology.registry as registry
    assert not hasattr(registry, "READ_PREFIXES")

    @registry.action("get_something_new", ontology="test-facts")
    class GetSomethingNew(registry.Action):
        pass

    assert GetSomethingNew.idempotent is False  # a reader's name alone does not make it idempotent


# ---------------------------------------------------------------- the readers of the table
class _Robot:
    def __init__(self, core):
        self.core, self.calls = core, []

    async def handle(self, req):
        held = [d for d in DEVICES if self.core.locks.holder(d) == "dyn@x"]
        self.calls.append((req.action_name, held))
        return None


def _core(estop: str | None = None):
    """The Core's RobotCommands member on a host with a task that may use every group."""
    async def nothing(*a, **k):
        return None

    host = SimpleNamespace(robot_id="nao-1", record_structure=lambda *a, **k: None, address="core@x", tracer=None,
                           tell_user=nothing, notify=nothing, in_background=lambda coro: coro.close(),
                           dynamic=SimpleNamespace(jid="dyn@x/r", rapp="r", ended=asyncio.Event(),
                                                   manifest=SimpleNamespace(robot_api=sorted(ROBOT_API_GROUPS))))
    core = RobotCommands(host, publish=nothing)
    core.estop_reason, core.estop_by = estop, "owner" if estop else None
    if estop is not None:
        core._estop_released.clear()
    host.robot = _Robot(core)
    return core


def _request(name: str, **fields):
    return actions("robot")[name].model_construct(**fields)


async def _no_feedback(progress):
    pass


def _ctx():
    return SimpleNamespace(sender="dyn@x", wants_feedback=False, feedback=_no_feedback,
                           info=SimpleNamespace(conversation_id="c-1"))  # a pass of s9 is traced under it


@pytest.mark.parametrize("name", ROBOT)
async def test_the_core_holds_motion_during_an_estop_and_locks_the_device(name):
    ctx = _ctx()
    core = _core(estop="bumper")
    core._only_supervisor(_request(name), ctx)  # not refused: a motion waits for the resume
    assert ACTION_FACTS[name].core is (name in CORE_SERVED)
    if ACTION_FACTS[name].core:
        return  # served by the Core itself (the locks; its pose estimate: tests/test_core_localizer.py)
    call = asyncio.create_task(core._robot_call(_request(name), ctx))
    await asyncio.sleep(0.05)
    assert call.done() is (name not in OLD_MOTION)  # a motion is held, anything else is served
    core.estop_reason = None
    core._estop_released.set()
    await call
    core = _core()
    core.driving = True
    await core._robot_call(_request(name), ctx)
    device = OLD_DEVICE.get(name)
    assert core.robot.calls == [(name, [device] if device else [])]
    assert core.locks.holder(device) is None if device else True  # freed after the call
    # move_vel without a velocity (the model's defaults) ends driving too
    assert core.driving is not (name in OLD_DRIVE_ENDS or name in OLD_DRIVE_SETS)


@pytest.mark.parametrize("velocity,driving", [({"x": 0.2}, True), ({"theta": -0.5}, True), ({}, False)])
async def test_a_velocity_keeps_the_base_driving(velocity, driving):
    core = _core()
    await core._robot_call(_request("move_vel", **{"x": 0.0, "y": 0.0, "theta": 0.0, **velocity}),
                           _ctx())
    assert core.driving is driving


@pytest.mark.parametrize("key", sorted(OLD_IDEMPOTENT))
async def test_a_timed_out_request_is_resent_only_when_idempotent(key):
    attempts = []

    async def once(to, content, timeout, performative, on_feedback=None):
        attempts.append(content.action_name)
        raise RequestTimeout("no answer")

    fake = SimpleNamespace(_request_once=once, address="me@x", tracer=SimpleNamespace(record=lambda *a, **k: None))
    content = actions(key[0])[key[1]].model_construct()
    with pytest.raises(RequestTimeout):
        await RappAgent.request(fake, "peer@x", content)
    assert len(attempts) == (3 if OLD_IDEMPOTENT[key] else 1)


# ---------------------------------------------------------------- the docs show the same table
def test_the_docs_table_is_the_code_table():
    text = (ROOT / "docs" / "architecture-actions.md").read_text()
    shown = re.search(r"<!-- ACTION_FACTS[^>]*-->\n(.*?)\n<!-- /ACTION_FACTS -->", text, re.S)
    assert shown, "docs/architecture-actions.md lost its ACTION_FACTS markers"
    assert shown.group(1) == markdown_table(), \
        "docs/architecture-actions.md differs from ontology/robot_actions.py: paste `python -m ontology.robot_actions`"


async def test_a_motion_blocked_just_after_the_safety_check_latched_the_stop_is_held_not_failed():
    """Both see the obstacle: the safety check latches the stop, and the robot's own collision
    protection stops the motion before the latch's stop interrupts it (CI failed a task so: its
    MotionBlocked went to the RApp while the wait-for-clear strategy had started)."""
    core = _core()
    core.safety_distance, core.fail_held = 0.10, None
    attempts = []

    async def handle(req):
        attempts.append(req.action_name)
        if len(attempts) == 1:
            core.estop_reason, core.estop_by = "obstacle ahead", "safety"
            core._estop_released.clear()
            raise MotionBlocked("nao: its collision protection stopped it")

    core.robot.handle = handle
    call = asyncio.create_task(core._robot_call(_request("move_along_path", poses=[]), _ctx()))
    await asyncio.sleep(0.05)
    assert not call.done(), "the blocked motion went back to the task"
    core.estop_reason = None
    core._estop_released.set()  # the strategy found the way clear
    await call
    assert attempts == ["move_along_path", "move_along_path"]
