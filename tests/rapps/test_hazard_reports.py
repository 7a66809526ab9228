"""The hazard task's reports: a checked or unreachable hazard is reported as text for the user and as
a HazardReport in the report's data; an unreachable one says why (planning, motion, localization or
the check failed). The task's own steps and FSMs run; only the agents it talks to are faked."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from agents.errors import RequestFailed, RequestTimeout
from behaviours.behaviour import Context
from ontology import core as C
from ontology.errors import ErrorCode
from ontology.manifest import load_manifest
from ontology.registry import Done
from ontology.robot import CameraInfo, JointAngles
from ontology.services.common import Pose2D
from ontology.services.home import DoorShape, HazardSpec, HomeInfo
from ontology.services.navigation import PlanPathReply
from ontology.spawn import RobotInfo
from rapps.hazard_detection.hazard_detection.models import HazardReport
from rapps.hazard_detection.hazard_detection.task import HazardTask, describe

RAPP = Path(__file__).resolve().parents[2] / "rapps" / "hazard_detection"
DOOR = HazardSpec(id="d1", type="door", stand=Pose2D(x=0.5, y=0.0, theta=0.0), look_at=[1.0, 0.0, 0.5],
                  door=DoorShape(hinge=[1.0, -0.45], closed_yaw_deg=90.0))


class FakeRuntime:
    """The Dynamic Agent as the task sees it, its requests to the Core and the Platform answered by
    `answers` (action name -> reply, or an exception to raise); unnamed actions get a default reply."""

    core, platform, token, address = "core@localhost", "platform@localhost", "token", "dyn@localhost"

    def __init__(self, **answers):
        self.manifest = load_manifest(RAPP)
        self.params = dict(self.manifest.params)
        self.robot_info = RobotInfo(robot_id="nao1", robot_type="nao")
        self.answers = answers
        self.reports: list[C.Report] = []
        self.event_handlers: dict = {}  # the Core's notifications (the plan monitor subscribes)

    async def request(self, to, content, timeout=None, **kw):
        if isinstance(content, C.Report):
            self.reports.append(content)
            return Done()
        answer = self.answers.get(content.action_name)
        if isinstance(answer, Exception):
            raise answer
        if answer is not None:
            return answer
        if content.reply_model is Pose2D:
            return Pose2D(x=0.0, y=0.0, theta=0.0)
        return content.reply_model()


def plan(found: bool = True) -> PlanPathReply:
    if not found:
        return PlanPathReply(plan_found=0, reason="the goal is inside an obstacle")
    return PlanPathReply(plan_found=1, path=[Pose2D(x=0.0, y=0.0, theta=0.0), Pose2D(x=0.5, y=0.0, theta=0.0)])


def memory_at_start() -> dict:
    return {"home": HomeInfo(home_id="home", map_id="m"), "hazard": DOOR, "results": [], "replans": 0,
            "blocked": 0, "localizations": [{"x": 0.0, "y": 0.0, "theta": 0.0}]}


async def go_to_hazard(runtime: FakeRuntime) -> tuple[HazardTask, dict]:
    """s4/s5 as the task's FSM runs them: navigation (its own sub-FSM, with the re-localization
    sub-FSM), and when it fails s5_unreachable, which reports."""
    task = HazardTask(runtime)
    top = task.build()
    assert any(t.source == "s4_5_go_to_hazard" and t.target == "s5_unreachable" and t.on_error
               for t in top.transitions)
    memory = memory_at_start()
    task.localizer.home = memory["home"]  # as s1_get_home hands it over
    outcome = await task.build_navigation().run(Context(memory=memory))
    assert outcome.error, "the navigation was meant to fail"
    await task.unreachable(memory)
    return task, memory


def the_report(runtime: FakeRuntime) -> tuple[str, HazardReport]:
    assert len(runtime.reports) == 1
    report = C.Report.model_validate_json(runtime.reports[0].model_dump_json())  # as the Core gets it
    return report.text, HazardReport.model_validate(report.data["hazard"])


async def test_no_path_is_said_in_the_report():
    runtime = FakeRuntime(path_planning_plan_path_2d=plan(found=False))
    _, memory = await go_to_hazard(runtime)
    text, data = the_report(runtime)
    assert text == "Hazard d1 (door): unknown. (no path: the goal is inside an obstacle)"
    assert data == HazardReport(id="d1", type="door", state="unknown", hazard=None)
    assert "error" not in memory  # said once, for this hazard only


async def test_failed_motion_is_said_in_the_report():
    runtime = FakeRuntime(path_planning_plan_path_2d=plan(),
                          move_along_path=RequestFailed("a wheel is stuck", code=ErrorCode.ERROR))
    await go_to_hazard(runtime)
    text, data = the_report(runtime)
    assert text == "Hazard d1 (door): unknown. (motion failed: a wheel is stuck)"
    assert data.state == "unknown" and data.hazard is None


async def test_failed_localization_is_said_in_the_report():
    # the leg is walked; re-localizing at its end, the head does not move
    runtime = FakeRuntime(path_planning_plan_path_2d=plan(),
                          get_joint_angles=JointAngles(joints=["HeadYaw", "HeadPitch"], angles=[0.0, 0.0]),
                          get_camera_info=CameraInfo(camera="top", width=4, height=3,
                                                     K=[[2.0, 0, 2.0], [0, 2.0, 1.5], [0, 0, 1]],
                                                     P=[[2.0, 0, 2.0, 0], [0, 2.0, 1.5, 0], [0, 0, 1, 0]],
                                                     hfov_deg=90.0, vfov_deg=73.7),
                          move_joint=RequestTimeout("no answer to move_joint within 30s"))
    await go_to_hazard(runtime)
    text, _ = the_report(runtime)
    assert text == "Hazard d1 (door): unknown. (localization failed: no answer to move_joint within 30s)"


async def test_failed_check_is_said_in_the_report():
    runtime = FakeRuntime(capture_image=RequestFailed("camera busy", code=ErrorCode.BUSY))
    task, memory = HazardTask(runtime), memory_at_start()
    with pytest.raises(RequestFailed):
        await task.check_hazard(memory)
    await task.unreachable(memory)
    text, _ = the_report(runtime)
    assert text == "Hazard d1 (door): unknown. (check failed: camera busy)"


def test_report_text_and_data_say_the_same():
    door = HazardReport(id="d1", type="door", state="open", hazard=True, angle_deg=37.26, method="edges")
    assert describe(door) == "Hazard d1 (door): open, 37.3 degrees."
    lamp = HazardReport(id="l1", type="lamp", state="off", hazard=False, light_level=0.1)
    assert describe(lamp) == "Hazard l1 (lamp): off."
    assert HazardReport.model_validate(door.model_dump()) == door


def test_the_scenario_reads_the_reports_data_from_the_task_record():
    """scenarios/hazard.py scores the data of the reports the Core kept in its task record
    (ontology/results.py), never the chat's text nor the trace: the closing summary, which carries
    no single hazard, is left out, whatever its size."""
    from ontology.results import ReportRecord, TaskRecord, TaskStage
    from scenarios.hazard import hazard_reports, reported

    found = [HazardReport(id="d1", type="door", state="open", hazard=True, angle_deg=37.26, method="edges"),
             HazardReport(id="l1", type="lamp", state="unknown", hazard=None)]
    summary = ReportRecord(text="Hazards found: the door d1 is open.", stamp=3.0,
                           data={"hazards": [f.model_dump() for f in found], "localizations": [{"x": 1.0}] * 200})
    reports = [ReportRecord(text=describe(f), data={"hazard": f.model_dump()}, stamp=1.0) for f in found] + [summary]
    record = TaskRecord(robot_id="nao1", rapp="hazard-detection", stage=TaskStage.RUN, state="Finished", ok=True,
                        reports=reports, ended=4.0)
    sent = TaskRecord.model_validate_json(record.fitted().model_dump_json())  # as the owner's client gets it
    assert hazard_reports(sent.reports) == found
    assert reported(found) == {"d1": {"state": "open", "angle": 37.3}, "l1": {"state": "unknown", "angle": None}}


async def test_a_door_frame_without_usable_lines_is_looked_at_again_from_the_next_view():
    """Issue 42: a frame whose floor lines do not pass where the camera looks (confidence below
    door_min_confidence) is not answered: the robot goes to the next view and looks again; the
    answer is the most confident look's, and says how sure it is."""
    from ontology.services.hazard import DoorAngle
    from rapps.hazard_detection.hazard_detection.models import DoorViewSpec

    answers = iter([DoorAngle(door_angle=4.1, method="image", confidence=0.1),
                    DoorAngle(door_angle=37.0, method="image", confidence=0.9)])
    from ontology.robot import Image

    runtime = FakeRuntime(capture_image=Image(camera="top", width=4, height=3, data_b64="AAAA"))
    task, memory = HazardTask(runtime), memory_at_start()
    original = runtime.request

    async def request(to, content, timeout=None, **kw):
        if content.action_name == "hazard_detection_door_check":
            return next(answers)
        return await original(to, content, timeout, **kw)

    runtime.request = request
    second = DoorViewSpec(x=1.5, y=-1.0, theta=2.0, look=[1.0, -0.45, 0.0], margin=3.0, distance_m=1.2, bearing_deg=45)
    memory.update(looks=[], views=[second], todo=[])
    assert await task.check_hazard(memory) == "again"
    assert (memory["goal"].x, memory["goal"].y) == (1.5, -1.0) and memory["views"] == []
    assert runtime.reports == []  # nothing said yet
    assert await task.check_hazard(memory) == "done"
    text, data = the_report(runtime)
    assert data.state == "open" and data.angle_deg == 37.0 and data.confidence == 0.9 and data.looks == 2
    assert text == "Hazard d1 (door): open, 37.0 degrees, confidence 0.90 (looked 2 times)."
    top = task.build()
    assert any(t.source == "s5_check_hazard" and t.target == "s4_5_go_to_hazard" for t in top.transitions)


async def test_blocked_again_at_the_same_place_it_is_marked_so_the_next_plan_is_another_way():
    """Issue 42: the first time a leg is blocked next to the map's walls the task takes it for the wall
    (its pose was off: it re-localizes); blocked again within AGAIN_M it marks it all the same, wider."""
    from ontology.services.navigation import ObstacleLayer
    from rapps.hazard_detection.hazard_detection.task import AGAIN_M, MAPPED_M
    from rapps.sdk.monitor import ECHO_RADIUS_M

    sent = []
    runtime = FakeRuntime()
    original = runtime.request

    async def request(to, content, timeout=None, **kw):
        if content.action_name == "path_planning_add_obstacle":
            sent.append(content)  # the first is the wall (not added), then each is added
            return ObstacleLayer(map_id="m", added=f"obs-{len(sent)}" if len(sent) > 1 else "", obstacles=[])
        return await original(to, content, timeout, **kw)

    runtime.request = request
    task, memory = HazardTask(runtime), memory_at_start()
    memory.update(blocks=[], leg_outcome="blocked")
    await task.mark_obstacle(memory, (0.5, 0.0))
    assert len(sent) == 1 and sent[0].skip_within_m == MAPPED_M and memory["leg_outcome"] == "late"  # re-localize
    memory["leg_outcome"] = "blocked"
    await task.mark_obstacle(memory, (0.5, 0.05))  # the robot is back where it was (0, 0)
    core, body = sent[1:]
    assert core.skip_within_m == 0.0 and (core.x, core.y) == (0.5, 0.05) and core.radius_m == ECHO_RADIUS_M
    radius = 1.5 * float(runtime.params["obstacle_radius_m"])  # wider, and behind the echo seen from (0, 0)
    assert body.radius_m == pytest.approx(radius) and math.dist((body.x, body.y), (0.5, 0.05)) == pytest.approx(radius)
    assert math.hypot(body.x, body.y) == pytest.approx(math.hypot(0.5, 0.05) + radius)
    assert math.dist(memory["blocks"][0], memory["blocks"][1]) <= AGAIN_M


def no_path_runtime(reason: str) -> tuple[FakeRuntime, list[str]]:
    """A runtime whose planner finds no path (`reason`), with the action of every request it is sent."""
    from ontology.services.navigation import ObstacleLayer

    sent: list[str] = []
    runtime = FakeRuntime(path_planning_plan_path_2d=PlanPathReply(plan_found=0, reason=reason),
                          path_planning_clear_obstacles=ObstacleLayer(map_id="m", obstacles=[]))
    original = runtime.request

    async def request(to, content, timeout=None, **kw):
        sent.append(content.action_name)
        return await original(to, content, timeout, **kw)

    runtime.request = request
    return runtime, sent


async def test_its_own_marks_blocking_every_route_are_cleared_once_and_the_plan_tried_again():
    """Issue 48 (lived in, NAO, generated house 85809): two marks, entered from a drifting estimate,
    closed every way to a lamp, which was reported unknown. The task clears its own marks once and
    plans again; only then, still no path, does it say so."""
    runtime, sent = no_path_runtime("the 2 temporary obstacle mark(s) on this map block every route")
    task, memory = HazardTask(runtime), memory_at_start()
    task.marks.marks = {"m1": ("m", (1.0, 0.0)), "m2": ("m", (1.2, 0.3))}
    with pytest.raises(RuntimeError, match="no path to d1"):
        await task.plan(memory)
    plans = [i for i, a in enumerate(sent) if a == "path_planning_plan_path_2d"]
    clears = [i for i, a in enumerate(sent) if a == "path_planning_clear_obstacles"]
    assert len(plans) == 2 and len(clears) == 2 and plans[0] < min(clears) and max(clears) < plans[1], sent
    assert task.marks.marks == {} and memory["marks_cleared"]
    sent.clear()  # once per hazard: the next failure is said at once
    task.marks.marks = {"m3": ("m", (1.0, 0.0))}
    with pytest.raises(RuntimeError):
        await task.plan(memory)
    assert sent.count("path_planning_plan_path_2d") == 1 and "path_planning_clear_obstacles" not in sent
    lamp = HazardSpec(id="l1", type="lamp", stand=Pose2D(x=0.5, y=0.0, theta=0.0), look_at=[1.0, 0.0, 1.4])
    memory["todo"] = [lamp]  # the next hazard may clear them once again
    assert await task.next_hazard(memory)
    sent.clear()
    task.marks.marks = {"m4": ("m", (1.0, 0.0))}
    with pytest.raises(RuntimeError, match="no path to l1"):
        await task.plan(memory)
    assert sent.count("path_planning_plan_path_2d") == 2 and "path_planning_clear_obstacles" in sent


async def test_marks_bodies_closing_every_route_are_dropped_first_their_echoes_kept():
    """Issue 48.6 (NAO, generated house 52169): the leaf of a door left half open narrowed the office's only
    doorway; the mark at its tip, a disc of the obstacle's guessed size, closed it, and clearing the marks
    sent the robot into the same leaf again. Now the bodies go first and the echoes stay."""
    from ontology.services.navigation import ObstacleLayer

    sent, live = [], {"core", "body"}
    runtime = FakeRuntime()
    original = runtime.request

    async def request(to, content, timeout=None, **kw):
        sent.append(content.action_name)
        if content.action_name == "path_planning_clear_obstacles":
            live.discard("body" if (content.x, content.y) == (1.3, 0.1) else "core")
            return ObstacleLayer(map_id="m", obstacles=[])
        if content.action_name == "path_planning_plan_path_2d":
            return plan("body" not in live)
        return await original(to, content, timeout, **kw)

    runtime.request = request
    task, memory = HazardTask(runtime), memory_at_start()
    task.marks.marks = {"m1": ("m", (1.0, 0.0))}
    task.marks.bodies = {"m1": ("m", "m2", (1.3, 0.1))}
    assert await task.plan(memory) == "move"
    assert [a for a in sent if a.startswith("path_planning")] == [
        "path_planning_plan_path_2d", "path_planning_clear_obstacles", "path_planning_plan_path_2d"]
    assert live == {"core"} and list(task.marks.marks) == ["m1"] and task.marks.bodies == {}
    assert not memory.get("marks_cleared")  # the once-per-hazard clearing is still left


async def test_a_mark_in_a_doorway_keeps_its_body_the_closed_door_is_reported():
    """What blocked the way in a doorway is its door, closed: its mark's body is not dropped to squeeze
    past it; the marks are cleared once, and with no way still the route is reported blocked."""
    from ontology.services.home import DoorwaySpec

    runtime, sent = no_path_runtime("the 1 temporary obstacle mark(s) on this map block every route")
    task, memory = HazardTask(runtime), memory_at_start()
    memory["home"] = HomeInfo(home_id="home", map_id="m", doors=[
        DoorwaySpec(id="d2", door=DoorShape(hinge=[1.0, -0.5], closed_yaw_deg=90.0, width_m=1.0))])
    memory["marked"] = [(1.02, 0.1)]
    task.marks.marks = {"m1": ("m", (1.02, 0.1))}
    task.marks.bodies = {"m1": ("m", "m2", (1.27, 0.1))}
    with pytest.raises(RuntimeError, match="no path to d1"):
        await task.plan(memory)
    assert sent.count("path_planning_plan_path_2d") == 2 and memory["marks_cleared"]  # no plan after a relax
    assert any(r.data["hazard"]["id"] == "route-d1" for r in runtime.reports), runtime.reports


def test_a_long_detour_is_followed_while_each_plan_is_nearer():
    """Issue 48.6 (NAO, generated house 51832): a door left half open closed the short way to a lamp; the
    14 m detour the planner found was given up after 40 plans (counted from the hazard's start), 3.7 m
    from the lamp. Plans that bring the robot nearer no longer count against it."""
    from rapps.hazard_detection.hazard_detection.task import MAX_PLANS, MAX_STALLED_PLANS, making_progress

    memory = {"replans": 0, "left_m": None, "stalled": 0}
    legs = [10.0 - 0.8 * k for k in range(8)] + [13.8 - 0.8 * k for k in range(17)]  # the way, then the detour
    lengths = [left for left in legs for _ in range(2)]  # each leg planned twice: turned first, then walked
    for left in lengths:
        memory["replans"] += 1
        assert making_progress(memory, left)
    assert memory["replans"] > 40
    assert memory["stalled"] == 1  # the last leg's two plans
    allowed = 1
    while allowed < 2 * MAX_STALLED_PLANS:  # then stuck: no plan nearer than the last
        memory["replans"] += 1
        if not making_progress(memory, 1.0 + 0.1 * (allowed % 2)):
            break
        allowed += 1
    assert allowed == MAX_STALLED_PLANS and memory["stalled"] == MAX_STALLED_PLANS + 1
    memory.update(replans=MAX_PLANS, left_m=None, stalled=0)  # and never more than MAX_PLANS in all
    memory["replans"] += 1
    assert not making_progress(memory, 0.4)


async def test_when_the_map_refuses_every_chosen_view_the_homes_own_stand_is_tried():
    """The view model chose stands the planner's map has no room for (generated house 33452: a door open
    79 deg, three views refused, the door reported unknown): the home's stand is the last resort."""
    goals = []

    class Runtime(FakeRuntime):
        async def request(self, to, content, timeout=None, **kw):
            if content.action_name == "path_planning_plan_path_2d":
                goals.append((content.goal.x, content.goal.y))
                if content.goal != DOOR.stand:
                    return PlanPathReply(plan_found=0, reason="goal pose is in an obstacle or too close to one for this robot")
                return plan()
            return await super().request(to, content, timeout, **kw)

    task = HazardTask(Runtime())
    views = [Pose2D(x=0.4, y=0.3, theta=0.0), Pose2D(x=0.4, y=-0.3, theta=0.0)]
    memory = {**memory_at_start(), "goal": views[0], "views": [type("V", (), {"x": v.x, "y": v.y, "theta": v.theta})()
                                                               for v in views[1:]]}
    assert await task.plan(memory) == "move"
    assert goals == [(0.4, 0.3), (0.4, -0.3), (0.5, 0.0)] and memory["goal"] == DOOR.stand


def estop_stopped() -> RequestFailed:
    return RequestFailed("move_to was interrupted by the emergency stop (obstacle ahead); a relative motion "
                         "is not resumed", code=ErrorCode.ESTOP)


async def test_a_turn_stopped_by_the_safety_is_a_blocked_leg_planned_again_from_where_it_stopped():
    """Elektron, generated 6121 (--realism full): backing off, the differential drive turned round and its
    collision protection stopped it; the Core fails a relative motion it will not resume (code estop), and
    the task gave the door up. A stopped turn counts as a blocked leg: re-localize and plan again, up to
    MAX_BLOCKED; any other failure gives the hazard up at once."""
    from rapps.hazard_detection.hazard_detection.task import MAX_BLOCKED
    task = HazardTask(FakeRuntime(move_to=estop_stopped()))
    memory = {**memory_at_start(), "turn": 1.0}
    for n in range(1, MAX_BLOCKED + 1):
        await task.turn(memory)
        assert memory["blocked"] == n and memory["leg_outcome"] == "late" and not memory["leg_final"]
        assert "error" not in memory
    with pytest.raises(RequestFailed):
        await task.turn(memory)
    assert memory["error"].startswith("(gave up: the way was blocked (move_to was interrupted")
    stuck = HazardTask(FakeRuntime(move_to=RequestFailed("a wheel is stuck", code=ErrorCode.ERROR)))
    memory = {**memory_at_start(), "turn": 1.0}
    with pytest.raises(RequestFailed):
        await stuck.turn(memory)
    assert memory["blocked"] == 0 and memory["error"] == "(motion failed: a wheel is stuck)"


async def test_a_back_off_stopped_by_the_safety_is_not_counted_twice():
    """The blocked leg before the back-off was counted (move_leg): its stopped back-off is not a second
    block of the same obstacle, and the task plans again from where it stopped."""
    from ontology.services.navigation import ObstacleLayer
    runtime = FakeRuntime(path_planning_plan_path_2d=plan(), move_to=estop_stopped(),
                          move_along_path=RequestFailed("the way ahead is blocked", code=ErrorCode.BLOCKED),
                          path_planning_add_obstacle=ObstacleLayer(map_id="m", added="obs-1", obstacles=[]))
    task = HazardTask(runtime)
    memory = memory_at_start()
    task.localizer.home = memory["home"]
    memory.update(leg=[Pose2D(x=0.0, y=0.0, theta=0.0), Pose2D(x=0.5, y=0.0, theta=0.0)], leg_final=False, turn=0.0)
    assert await task.move_leg(memory) == "back off" and memory["blocked"] == 1
    await task.back_off(memory)
    assert memory["blocked"] == 1 and memory["leg_outcome"] == "late" and "error" not in memory
