"""Hazard-detection task (paper 000 fig. 16): s1 get the home map and hazard list from the Platform,
s2 self-localize (sub-FSM), then for every hazard s3/s4 plan a path from the pose to the hazard's
standing pose, s5 follow it leg by leg re-localizing at the way-points (sub-FSM), look at the hazard
and check it; s6 report the hazards to the Core; s7 finishing the FSM tells the Core we are done."""
from __future__ import annotations

import asyncio
import math

from ontology import robot_types
from ontology.services.common import CameraIntrinsics, Pose2D
from ontology.services.hazard import DoorGeometry
from rapps.sdk import FSM, ArriveBy, ErrorCode, Localized, PathFree, PlanFailed, PlanMonitor, RequestError, Step, Task
from rapps.sdk.paths import cut_path, path_length, point_at
from rapps.sdk.paths import first_leg as sdk_first_leg

from .models import ONTOLOGY, CameraSpec, HazardReport

PLAN_FOUND = 1
FINAL_LEG_SLACK = 1.25  # the whole rest of the path is one leg when at most this many legs long
MAX_BLOCKED = 4  # blocked legs per hazard before giving it up
MAPPED_M = 0.12  # an obstacle this close to the map's walls is the wall (the pose estimate was off)
DOORWAY_M = 0.35  # an obstacle this close to a doorway's line is in that doorway
# a leg is at most as long as keeps the pose filter's predicted sideways error (1 sigma) within this:
# three sigma stay inside the 10 cm tracking goal (params: leg_cross_track_std_m)
LEG_CROSS_TRACK_STD_M = 0.035
RELOCALIZE_LEG_M = 0.4  # re-localize when the pose filter allows no leg this long (params: relocalize_leg_m)
# a leg through a stretch where no code is in reach may run on to where one is, while the filter's predicted
# sideways error there stays within half the tracking tolerance: paper 001 sec. 4's figure for the robot type
# (ontology.robot_types), or params: tracking_tolerance_m; a robot type the paper had not gets this
TRACKING_TOLERANCE_M = 0.15
FIX_STEP_M = 0.1  # how finely a leg's end is moved to where a fix is predicted
# a leg through a stretch without codes in reach may end where the head can fix the pose this many times
# less certainly than a trusted fix (5 cm, 0.02 rad): beyond a doorway, a far pair of codes still puts the
# heading right, which the drift grows from (elsewhere legs end where a trusted fix is predicted)
FIX_SLACK = 2.5
AGAIN_M = 0.5  # blocked again within this of where a leg was blocked before: the same obstacle
# a hazard is given up after this many plans in a row that left the robot no nearer (PROGRESS_M shorter
# a path than the last), or this many plans in all: a detour round a blocked door may take 30 legs
MAX_STALLED_PLANS = 25
MAX_PLANS = 100
PROGRESS_M = 0.2


def making_progress(memory: dict, left_m: float) -> bool:
    """Counts a plan of `left_m` metres to the goal: False when the hazard should be given up (too many
    plans in a row no nearer than the one before, or too many in all)."""
    last = memory.get("left_m")
    stalled = 0 if last is not None and left_m < last - PROGRESS_M else memory.get("stalled", 0) + (last is not None)
    memory["left_m"], memory["stalled"] = left_m, stalled
    return stalled <= MAX_STALLED_PLANS and memory["replans"] <= MAX_PLANS


def leg_rotation(poses, turn: float, final: bool) -> float:
    """About how far (rad) the base turns on a leg: the turn it starts with, then to the bearing of its
    last segment (or, on the final leg, to the standing pose's heading)."""
    if len(poses) < 2:
        return abs(turn)
    start = math.atan2(poses[1].y - poses[0].y, poses[1].x - poses[0].x)
    end = poses[-1].theta if final else math.atan2(poses[-1].y - poses[-2].y, poses[-1].x - poses[-2].x)
    return abs(turn) + abs(math.remainder(end - start, math.tau))


def first_leg(poses, leg: float) -> tuple[list, bool]:
    """The path up to about `leg` metres (the whole path if little more is left); True if final.
    Odometry's systematic heading drift (~0.05 rad/m) puts the robot off a straight path by ~2.5 cm
    times the squared distance, so the last leg may be only a quarter longer: 1.4 m, not 1.65."""
    return sdk_first_leg(poses, leg, FINAL_LEG_SLACK)


def leg_to_fix(poses, leg: float, fixable, blind_m: float, weak=None, step: float = FIX_STEP_M
               ) -> tuple[list, bool] | None:
    """A leg that ends where a fix is predicted (`fixable(pose)`), when the leg of `leg` metres would end
    where none is: cut back to the farthest such point in its second half, else run on to the nearest
    point within `blind_m` where at least a weaker fix is predicted (`weak`, default `fixable`; the path's
    end counts: the standing pose is localized anyway). None: the leg of `leg` metres stays (its end can
    fix, or no such point is near). (poses, final) otherwise."""
    weak = weak or fixable
    total = path_length(poses)
    if leg >= total or fixable(point_at(poses, leg)):
        return None
    s = leg - step
    while s >= leg / 2:
        if fixable(point_at(poses, s)):
            return cut_path(poses, s), False
        s -= step
    s = leg + step
    while s <= blind_m:
        if s >= total - step:
            return list(poses), True
        if weak(point_at(poses, s)):
            return cut_path(poses, s), False
        s += step
    return None


def tracking_tolerance(param, robot_type: str) -> float:
    """The tracking tolerance (m) for this robot: the param when set, else the paper's figure for its type,
    else TRACKING_TOLERANCE_M."""
    if param is not None:
        return float(param)
    facts = robot_types.ROBOT_TYPES.get(robot_type)
    figure = facts.paper_tracking_m if facts else None
    return figure if figure is not None else TRACKING_TOLERANCE_M


def next_leg_action(path, theta: float, leg: float, turn_first: float, *, localized: bool,
                    turned: bool) -> tuple[str, float, float]:
    """("turn" | "move", the turn the leg starts with, the leg's length). Odometry drifts with the
    square of the distance and loses ~0.02 rad of heading per sqrt(rad) turned, so a leg that starts
    far off the heading is turned on the spot and re-localized first ("turn"), once: a re-localization
    that looked behind leaves the robot facing away again, and the leg it then walks with a big turn
    and no fix is half length, like one after a failed localization."""
    if not localized:
        leg /= 2
    if len(path) < 2:
        return "move", 0.0, leg
    turn = math.remainder(math.atan2(path[1].y - path[0].y, path[1].x - path[0].x) - theta, math.tau)
    if abs(turn) <= turn_first:
        return "move", turn, leg
    if turned:
        return "move", turn, leg / 2
    return "turn", turn, leg


class HazardTask(Task):
    cloud_ontology = ONTOLOGY

    def build(self) -> FSM:
        # s2 and n3 are the SDK's localization sub-FSM (rapps/sdk/localize.py), its settings from params
        fsm = FSM("hazard_detection", initial="s1_get_home")
        fsm.add_state("s1_get_home", Step(self.get_home))
        fsm.add_state("s2_localize", self.localizer.build("s2_localize"))
        fsm.add_state("s3_next_hazard", Step(self.next_hazard))
        fsm.add_state("s4_5_go_to_hazard", self.build_navigation())
        fsm.add_state("s5_check_hazard", Step(self.check_hazard))
        fsm.add_state("s5_unreachable", Step(self.unreachable))
        fsm.add_state("s6_report", Step(self.report_hazards))
        fsm.add_state("s7_done", Step(self.done), final=True)
        fsm.add_transition("s1_get_home", "s2_localize")
        fsm.add_transition("s2_localize", "s3_next_hazard")
        fsm.add_transition("s3_next_hazard", "s4_5_go_to_hazard", when=lambda m, o: o.value)
        fsm.add_transition("s3_next_hazard", "s6_report", when=lambda m, o: not o.value)
        fsm.add_transition("s4_5_go_to_hazard", "s5_check_hazard")
        fsm.add_transition("s4_5_go_to_hazard", "s5_unreachable", on_error=True)
        fsm.add_transition("s5_check_hazard", "s4_5_go_to_hazard", when=lambda m, o: o.value == "again")
        fsm.add_transition("s5_check_hazard", "s3_next_hazard", when=lambda m, o: o.value != "again")
        fsm.add_transition("s5_check_hazard", "s5_unreachable", on_error=True)
        fsm.add_transition("s5_unreachable", "s2_localize")  # where are we after the failure?
        fsm.add_transition("s6_report", "s7_done")
        return fsm

    def build_navigation(self) -> FSM:
        """s3/s4 plan from the current pose, s5 move one leg, re-localize; until the standing pose.
        Each leg runs under a plan monitor (paper 004: rapps/sdk/monitor.py) expecting the robot at the
        leg's end in time and the way free. A leg blocked by an obstacle enters it into the Platform's
        map (unless it is the map's own wall: the pose estimate was off near a door frame), backs off
        the way it came, re-localizes and plans again, round it; a late leg, or one the pose filter is lost
        on (its position std above lost_std_m), re-localizes and plans again."""
        nav = FSM("navigate", initial="n1_plan")
        nav.add_state("n1_plan", Step(self.plan))
        nav.add_state("n1_turn", Step(self.turn))
        nav.add_state("n2_move_leg", Step(self.move_leg))
        nav.add_state("n2_back_off", Step(self.back_off))
        nav.add_state("n3_uncertain", Step(self.uncertain))
        nav.add_state("n3_relocalize", self.localizer.build("n3_relocalize"))
        nav.add_state("n4_arrived", Step(self.arrived), final=True)
        # a leg starting far off the robot's heading: turn on the spot and re-localize first
        # (odometry loses ~0.02 rad of heading per sqrt(rad) turned)
        nav.add_transition("n1_plan", "n1_turn", when=lambda m, o: o.value == "turn")
        nav.add_transition("n1_plan", "n2_move_leg", when=lambda m, o: o.value != "turn")
        nav.add_transition("n1_turn", "n3_relocalize")
        nav.add_transition("n2_move_leg", "n2_back_off", when=lambda m, o: o.value == "back off")
        nav.add_transition("n2_move_leg", "n3_uncertain", when=lambda m, o: o.value != "back off")
        nav.add_transition("n2_back_off", "n3_uncertain")
        # re-localize where the pose filter is too uncertain for the next leg (or the leg was late, or
        # this is the standing pose), not after every short leg or back-off
        nav.add_transition("n3_uncertain", "n3_relocalize", when=lambda m, o: o.value)
        nav.add_transition("n3_uncertain", "n1_plan", when=lambda m, o: not o.value)
        nav.add_transition("n3_relocalize", "n4_arrived", when=lambda m, o: m["leg_final"])
        nav.add_transition("n3_relocalize", "n1_plan", when=lambda m, o: not m["leg_final"])
        return nav

    # -- s1 ---------------------------------------------------------------------------------
    async def get_home(self, memory):
        info = await self.platform.home_get_info(home_id=str(self.params.get("home", "home")))
        memory["home"] = info
        self.localizer.home = info  # its landmarks and rooms
        memory["todo"] = list(info.hazards)
        memory["results"] = []
        self.log.info("%d possible hazards in home %s", len(info.hazards), info.home_id)
        self.progress(0.0, f"{len(info.hazards)} hazards to check")
        await self.say(f"Checking {len(info.hazards)} possible hazards.")

    # -- s3 ---------------------------------------------------------------------------------
    async def next_hazard(self, memory) -> bool:
        if not memory["todo"]:
            return False
        pose = await self.robot.get_global_pose()
        # nearest first (greedy tour)
        memory["todo"].sort(key=lambda h: math.hypot(h.stand.x - pose.x, h.stand.y - pose.y))
        hazard = memory["hazard"] = memory["todo"].pop(0)
        memory["replans"] = memory["blocked"] = memory["stalled"] = 0
        memory["left_m"] = None  # the last plan's length (making_progress)
        memory["blocks"] = []  # where legs to this hazard were blocked
        memory["marks_cleared"] = False  # plan(): the task's own marks may be cleared once per hazard
        memory["looks"] = []  # (answer, where from) of each look at a door
        memory["views"] = await self.door_views(memory, hazard) if hazard.type == "door" else []
        memory["goal"] = self.view_pose(memory["views"].pop(0)) if memory["views"] else hazard.stand
        self._show(memory, 0.0, "on the way")
        return True

    async def door_views(self, memory, h) -> list:
        """Where to stand for the door check (view.py, on the Cloud Agent): best first, from the door's
        geometry, the home's rooms and this robot's camera; [] (the home's own stand) when it has none
        or the Cloud Agent cannot say."""
        if not self.params.get("choose_door_views", True) or h.door is None:
            return []
        try:
            if getattr(self, "camera_spec", None) is None:
                res = self.params["check_resolution"]
                info = await self.robot.get_camera_info(resolution=res)
                at = await self.robot.get_transform(chain="camera", space="robot")
                self.camera_spec = camera_spec(info.K, res, at.matrix)
            home = memory["home"]
            room = next((r for r in home.rooms if r.name == h.room), None)
            reply = await self.cloud.call("door_views", _timeout=180.0, door=h.door, robot_side=[h.stand.x, h.stand.y],
                                          camera=self.camera_spec, rooms=home.rooms, doors=home.doors, room=room,
                                          open_threshold_deg=float(self.params["door_open_image_deg"]))
        except RequestError as e:
            self.log.warning("no views for %s: %s; standing where the home description says", h.id, e)
            return []
        return list(reply.views)

    @staticmethod
    def view_pose(view) -> Pose2D:
        return Pose2D(x=view.x, y=view.y, theta=view.theta)

    def _show(self, memory, fraction: float, text: str) -> None:
        """Progress: hazards done, plus how far the current one is (0..1)."""
        done, total = len(memory["results"]), len(memory["results"]) + len(memory["todo"]) + 1
        self.progress(min(1.0, (done + fraction) / total), f"{memory['hazard'].id}: {text}")

    # -- s4/s5 ------------------------------------------------------------------------------
    async def plan(self, memory):
        hazard = memory["hazard"]
        pose = await self.robot.get_global_pose()
        memory.setdefault("goal", hazard.stand)
        while True:
            reply = await self.platform.path_planning_plan_path_2d(
                map_id=memory["home"].map_id, robot_type=self.robot_type(), algorithm=self.params["algorithm"],
                start=pose, goal=memory["goal"])
            if reply.plan_found != PLAN_FOUND and self.marks.bodies:
                # the marks' bodies (each obstacle's guessed size behind its echo) close every way: a
                # half-open door or a box beside a doorway narrowed the passage; the echoes alone may not.
                # What was met in a doorway is its door, closed: that body stays
                doors = memory["home"].doors
                dropped = await self.marks.relax(keep=lambda p: bool(blocking_doors(doors, [p])))
                if dropped:
                    self.log.info("the obstacle marks' bodies block every route to %s: %d dropped, the echoes "
                                  "kept, planning again", hazard.id, dropped)
                    continue
            if reply.plan_found != PLAN_FOUND and self.marks.marks and not memory.get("marks_cleared"):
                # this task's own marks close every way: placed from a drifting estimate, or round
                # something since moved, they may be wrong; cleared once, the range sensors judge again
                memory["marks_cleared"] = True
                self.log.info("the %d obstacle marks block every route to %s: cleared, planning again",
                              len(self.marks.marks), hazard.id)
                for mark_id in list(self.marks.marks):
                    await self.marks.clear(mark_id)
                continue
            if reply.plan_found == PLAN_FOUND or "goal pose" not in reply.reason:
                break
            if memory.get("views"):  # a stand the map has no room for: the next view
                memory["goal"] = self.view_pose(memory["views"].pop(0))
            elif memory["goal"] != hazard.stand:  # every chosen view refused: the home's own stand, last
                memory["goal"] = hazard.stand
            else:
                break
        if reply.plan_found != PLAN_FOUND:
            blocked = blocking_doors(memory["home"].doors, memory.get("marked", []))
            if blocked:  # the map's way there went through a door found closed: a hazard of its own
                await self.report_blocked_route(memory, blocked)
            memory["error"] = f"(no path: {reply.reason})"  # said in the report of this hazard
            raise RuntimeError(f"no path to {hazard.id}: {reply.reason}")
        memory["replans"] += 1
        if not making_progress(memory, reply.length_m):
            memory["error"] = f"(gave up after {memory['replans']} plans, {memory['stalled']} of them no nearer)"
            raise RuntimeError(f"could not reach {hazard.id}")
        history = self.localizer.history
        localized = bool(history) and history[-1].fixed
        longest = self.localizer.leg_length(
            float(self.params["leg_length_m"]),
            float(self.params.get("leg_cross_track_std_m", LEG_CROSS_TRACK_STD_M)))
        action, memory["turn"], leg = next_leg_action(
            reply.path, pose.theta, longest, float(self.params["turn_first_rad"]),
            localized=localized, turned=bool(memory.pop("leg_turned", False)))
        memory["leg"], memory["leg_final"] = first_leg(reply.path, leg)
        memory["fix_at_end"] = False
        if action == "move" and not memory["leg_final"]:
            moved = await asyncio.to_thread(self.end_at_fix, reply.path, path_length(memory["leg"]))
            if moved is not None:
                memory["leg"], memory["leg_final"] = moved
                memory["fix_at_end"] = not memory["leg_final"]
        return action

    def end_at_fix(self, path, leg: float) -> tuple[list, bool] | None:
        """The leg moved to end where the head can fix the pose (a doorway, a stretch without codes in
        reach: re-localize before it and walk through it in one leg, not in short legs begun from a
        drifting estimate), and whether it is now the final one; None: the leg stays. numpy: off the
        event loop (it reads the filter, writes nothing)."""
        if self.localizer.ekf is None or self.localizer.camera is None:  # nothing localized yet: no map of fixes
            return None
        tolerance = tracking_tolerance(self.params.get("tracking_tolerance_m"), self.robot_type())
        blind = self.localizer.leg_length(path_length(path), tolerance / 2, shortest=0.0)
        return leg_to_fix(path, leg, lambda p: self.localizer.fixable((p.x, p.y, p.theta)), blind,
                          weak=lambda p: self.localizer.fixable((p.x, p.y, p.theta), FIX_SLACK))

    async def turn(self, memory):
        memory["leg_final"] = False
        memory["leg_turned"] = True
        try:
            await self.robot.move_to(x=0.0, y=0.0, theta=memory["turn"], _timeout=60.0)
        except RequestError as e:
            if not self.stopped_midway(memory, e):
                raise
        finally:
            self.localizer.moved(rotation=memory["turn"])

    async def move_leg(self, memory) -> str:
        leg = memory["leg"]
        self.localizer.moved(path_length(leg), leg_rotation(leg, memory["turn"], memory["leg_final"]))
        within = path_length(leg) / float(self.params["leg_speed_floor_mps"]) + float(self.params["leg_slack_s"])
        monitor = PlanMonitor(self, ArriveBy(leg[-1], within_s=within), PathFree(leg),
                              Localized(self.localizer.position_std, float(self.params["lost_std_m"])))
        memory["leg_outcome"] = "moved"
        try:
            await monitor.run(self.robot.move_along_path(poses=leg, _timeout=900.0,  # feedback: shown as progress
                                                         _feedback=lambda p: self._show(memory, 0.0, p.text)))
        except PlanFailed as e:
            memory["leg_final"] = False  # not there: plan again from where it stopped
            if memory["blocked"] >= MAX_BLOCKED:
                memory["error"] = f"(gave up: {e.reason})"
                raise
            memory["blocked"] += 1
            if e.expectation != PathFree.name:
                memory["leg_outcome"] = "late"  # or lost: re-localize, then plan again from where it is
                return "late"
            memory["leg_outcome"] = "blocked"
            await self.mark_obstacle(memory, e.obstacle)
            return "blocked" if e.backed_off else "back off"  # the Core's strategies backed off already
        except RequestError as e:
            memory["error"] = f"(motion failed: {e.reason})"
            raise
        return "moved"

    async def mark_obstacle(self, memory, where) -> None:
        """Enter what blocked the leg into the Platform's map, so that the next plan goes round it
        (where the range sensors saw it; else just ahead of the robot). Near the map's walls it is
        taken for the wall (the pose estimate was off) unless the way was blocked there before: then
        it is marked all the same, and wider, so that the next plan is another way, not the same."""
        pose = await self.robot.get_global_pose()
        if where is None:
            ahead = float(self.params["back_off_m"]) + 0.3
            where = (pose.x + ahead * math.cos(pose.theta), pose.y + ahead * math.sin(pose.theta))
        blocks = memory.setdefault("blocks", [])
        again = sum(math.dist(b, (pose.x, pose.y)) <= AGAIN_M for b in blocks)
        blocks.append((pose.x, pose.y))
        radius = float(self.params["obstacle_radius_m"]) * (1.0 + 0.5 * again)
        added = await self.marks.enter(memory["home"].map_id, where[0], where[1], radius_m=radius,
                                       ttl_s=float(self.params["obstacle_ttl_s"]),
                                       skip_within_m=0.0 if again else MAPPED_M, seen_from=(pose.x, pose.y),
                                       note=f"blocked the way to {memory['hazard'].id}")
        if added:
            memory.setdefault("marked", []).append(tuple(where))
        else:  # a door frame, a passage door's leaf: re-localize before the same plan is tried again
            self.log.info("what blocked the leg at (%.2f, %.2f) is the map's wall", *where)
            memory["leg_outcome"] = "late"

    async def back_off(self, memory):
        memory["leg_final"] = False
        self.localizer.moved(float(self.params["back_off_m"]))
        try:
            await self.robot.move_to(x=-float(self.params["back_off_m"]), _timeout=60.0)
        except RequestError as e:
            if not self.stopped_midway(memory, e, leg_counted=True):  # the leg that led here was counted
                raise

    def stopped_midway(self, memory, e: RequestError, leg_counted: bool = False) -> bool:
        """A turn or back-off stopped by an emergency stop (the Core fails a relative motion it will not
        resume, code estop: the robot's collision protection, a differential drive backing off by turning
        round into what it stops for, or the owner): a blocked leg, unless `leg_counted` (a back-off
        after one); the task re-localizes and plans again from where it stopped. False, with the reason
        in memory["error"], for any other failure and after MAX_BLOCKED blocked legs (give it up)."""
        if e.code != ErrorCode.ESTOP:
            memory["error"] = f"(motion failed: {e.reason})"
            return False
        if not leg_counted:
            if memory["blocked"] >= MAX_BLOCKED:
                memory["error"] = f"(gave up: the way was blocked ({e.reason}))"
                return False
            memory["blocked"] += 1
        memory["leg_final"], memory["leg_outcome"] = False, "late"
        self.log.info("the motion was stopped midway (%s): planning again from here", e.reason)
        return True

    async def uncertain(self, memory) -> bool:
        """Whether to re-localize now: at the standing pose (the check and the score need the best
        pose), after a late or lost leg, or when the pose filter no longer allows a leg of
        `relocalize_leg_m` (params); not after a short leg or a back-off that left the pose certain."""
        if memory["leg_final"] or memory.get("leg_outcome") == "late":
            return True
        if memory.pop("fix_at_end", False) and memory.get("leg_outcome") == "moved":
            return True  # the leg was ended where a fix is predicted: take it
        await self.localizer.track()
        longest = self.localizer.leg_length(
            float(self.params["leg_length_m"]),
            float(self.params.get("leg_cross_track_std_m", LEG_CROSS_TRACK_STD_M)))
        return longest < float(self.params.get("relocalize_leg_m", RELOCALIZE_LEG_M))

    async def arrived(self, memory):
        pass

    def robot_type(self) -> str:
        return self.robot_info.robot_type  # told by the runtime, not guessed

    # -- s5: look and check -----------------------------------------------------------------
    async def check_hazard(self, memory) -> str:
        """Check the hazard; "again" when a door's frame had no usable lines and another view is left:
        the robot goes there and looks again before it answers."""
        h = memory["hazard"]
        try:
            if h.type == "door":
                reply = await self.check_door(h)
                memory.setdefault("looks", []).append(reply)
                if reply.confidence < float(self.params["door_min_confidence"]) and memory.get("views"):
                    memory["goal"] = self.view_pose(memory["views"].pop(0))
                    self._show(memory, 0.0, f"no usable lines (confidence {reply.confidence:.2f}): looking again")
                    return "again"
                result = door_report(h, memory["looks"], self.params)
            else:
                result = await self.check_lamp(h)
        except RequestError as e:
            memory["error"] = f"(check failed: {e.reason})"
            raise
        memory["results"].append(result)
        await self.report(describe(result), hazard=result.model_dump())
        return "done"

    async def check_door(self, h):
        """One look at the door: the check's answer (DoorAngle, with its confidence)."""
        method, res = self.params["door_method"], self.params["check_resolution"]
        x, y, z = door_look_point(h, method)
        await self.robot.look_at_point(x=x, y=y, z=z)
        image = await self.robot.capture_image(resolution=res)
        request = dict(image_b64=image.data_b64, method=method)
        if method == "geometry":
            info = await self.robot.get_camera_info(resolution=res)
            tf = await self.robot.get_transform(chain="camera", space="global")
            request["geometry"] = door_geometry(info.K, tf.matrix, h)
        return await self.platform.hazard_detection_door_check(**request)

    async def check_lamp(self, h) -> HazardReport:
        """As the original RApp: a low-exposure image (only light sources stay bright) for the light
        check, the camera's parameters restored afterwards whatever happens."""
        saved = await self.robot.set_camera_params()  # no field set: changes nothing, answers the current ones
        try:
            await self.robot.set_camera_params(exposure=float(self.params["light_exposure"]), auto_exposure=False)
            await self.robot.look_at_point(x=h.look_at[0], y=h.look_at[1], z=h.look_at[2])
            image = await self.robot.capture_image(resolution=self.params["light_resolution"])
        finally:
            await self.robot.set_camera_params(exposure=saved.exposure, auto_exposure=saved.auto_exposure)
        reply = await self.platform.hazard_detection_light_check(image_b64=image.data_b64,
                                                                 on_threshold=int(self.params["light_on_level"]))
        return HazardReport(id=h.id, type="lamp", state="on" if reply.lamp_on else "off",
                            light_level=reply.light_level, hazard=reply.lamp_on, confidence=reply.confidence)

    async def report_blocked_route(self, memory, doors) -> None:
        """A door on the only route to a hazard is closed: reported as a hazard of its own."""
        h = memory["hazard"]
        names = " and ".join(doors)
        result = HazardReport(id=f"route-{h.id}", type="route", state="blocked", hazard=True,
                              blocked_by=[f"door {d}" for d in doors])
        memory["results"].append(result)
        memory["error"] = f"(the way there is blocked: door {names} closed)"
        await self.report(f"Hazard route-{h.id} (route): blocked, the door {names} is closed on the only way "
                          f"to {h.id}.", hazard=result.model_dump())

    async def unreachable(self, memory):
        """s5 failed on the way or at the check: the hazard is reported unknown, with the reason the
        failing step left in memory["error"] (planning, motion, localization or the check)."""
        h = memory["hazard"]
        reason = memory.pop("error", "")  # this hazard's, never a stale one
        memory.pop("marked", None)
        result = HazardReport(id=h.id, type=h.type, state="unknown", hazard=None)
        memory["results"].append(result)
        await self.report(describe(result) + (f" {reason}" if reason else ""), hazard=result.model_dump())

    # -- s6/s7 ------------------------------------------------------------------------------
    async def report_hazards(self, memory):
        results = memory["results"]
        found = [r for r in results if r.hazard]
        if found:
            text = "Hazards found: " + "; ".join(f"the {r.type} {r.id} is {r.state}" for r in found) + "."
        elif all(r.state != "unknown" for r in results):
            text = f"No hazards: all {len(results)} checked doors are closed and lamps off."
        else:
            text = "No hazards found, but not everything could be checked."
        self.progress(1.0, f"{len(results)} hazards checked, {len(found)} found")
        await self.report(text, hazards=[r.model_dump() for r in results],
                          localizations=[e.as_dict() for e in self.localizer.history],
                          localization=self.localizer.stats())

    async def done(self, memory):
        await self.say("Hazard check finished.")


def camera_spec(K, resolution: str, camera_in_robot) -> CameraSpec:
    """The check's camera for the view model: intrinsics at `resolution`, height and how far ahead of
    the base it sits (get_transform(chain="camera", space="robot"))."""
    w, h = (int(v) for v in resolution.split("x"))
    return CameraSpec(intrinsics=CameraIntrinsics(fx=K[0][0], fy=K[1][1], cx=K[0][2], cy=K[1][2]), width=w, height=h,
                      z=camera_in_robot[2][3], ahead=camera_in_robot[0][3])


def door_report(h, looks, params: dict) -> HazardReport:
    """The answer of the most confident look at a door (the last one among equals)."""
    best = max(reversed(looks), key=lambda r: r.confidence)
    is_open = best.door_angle > door_open_threshold(params, best.method)
    return HazardReport(id=h.id, type="door", state="open" if is_open else "closed", angle_deg=best.door_angle,
                        method=best.method, hazard=is_open, confidence=best.confidence, looks=len(looks))


def blocking_doors(doorways, marked) -> list[str]:
    """The doors whose doorway holds an obstacle the task entered (what blocked it there is the door)."""
    out = []
    for d in doorways:
        hinge, yaw, width = d.door.hinge, math.radians(d.door.closed_yaw_deg), d.door.width_m
        latch = (hinge[0] + width * math.cos(yaw), hinge[1] + width * math.sin(yaw))
        if any(segment_distance(p, hinge, latch) <= DOORWAY_M for p in marked):
            out.append(d.id)
    return out


def segment_distance(p, a, b) -> float:
    dx, dy = b[0] - a[0], b[1] - a[1]
    t = max(0.0, min(1.0, ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / (dx * dx + dy * dy or 1.0)))
    return math.hypot(p[0] - a[0] - t * dx, p[1] - a[1] - t * dy)


def door_geometry(K, camera_to_world, h) -> DoorGeometry:
    """What the geometry method needs: the camera's intrinsics and pose, and the door's shape."""
    return DoorGeometry(camera=CameraIntrinsics(fx=K[0][0], fy=K[1][1], cx=K[0][2], cy=K[1][2]),
                        camera_to_world=camera_to_world, hinge=h.door.hinge,
                        closed_yaw_deg=h.door.closed_yaw_deg, width_m=h.door.width_m)


def door_look_point(h, method: str) -> tuple[float, float, float]:
    """Where the camera looks for a door check. The original image-only method needs the camera
    pointed at where the door frame meets the floor, the hinge (its two floor lines then fall one in
    each half of the image); the geometry method looks at the hazard's own point."""
    if method == "image" and h.door is not None:
        return h.door.hinge[0], h.door.hinge[1], 0.0
    return h.look_at[0], h.look_at[1], h.look_at[2]


def door_open_threshold(params: dict, method: str) -> float:
    """Degrees above which a door is open: the image-only answer is an angle in the image, about
    half the opening near closed (docs/hazard-validation.md), so it has its own threshold."""
    return float(params["door_open_image_deg"] if method == "image" else params["door_open_deg"])


def describe(r: HazardReport) -> str:
    """One line per hazard for the user: 'Hazard <id> (<type>): <state>[, <n> degrees].' (the
    report's data carries the same as a HazardReport)."""
    text = f"Hazard {r.id} ({r.type}): {r.state}"
    if r.type == "door" and r.angle_deg is not None:
        text += f", {r.angle_deg:.1f} degrees"
    if r.confidence is not None:
        text += f", confidence {r.confidence:.2f}" + (f" (looked {r.looks} times)" if r.looks > 1 else "")
    return text + "."
