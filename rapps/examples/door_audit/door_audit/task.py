"""Door audit: for each door of the home (or of one room), go to a check pose, localize by the QR
landmarks in sight, check the door, and report the list (which doors are open, by how much).

The door check's geometry is only as good as the robot's pose estimate, and get_global_pose is
odometry that drifts (a NAO walking a few metres is tens of centimetres off): so the robot localizes
by the home's landmarks (qr_detection with each code's own size, compute_global_pose,
set_global_pose) every few metres and at the check pose, and steps onto it again before it looks. A
walk the Core's safety gave up on (`blocked`) is planned again from where the robot stands."""
import math

from ontology.services.home import DoorCheckPose, DoorwaySpec, HomeInfo
from ontology.services.localization import MarkerObservation
from rapps.sdk import FSM, ErrorCode, Key, RequestFailed, Sequence, Step, Task, check_door, intrinsics
from rapps.sdk.paths import first_leg

LOCALIZE_RESOLUTION = "1280x960"  # a 0.25 m code decodes to ~4 m, a 0.35 m one to ~5 m
MAX_CODE_M = 4.5
LEG_M = 3.0  # the longest walk without localizing


class DoorAudit(Task):
    keys = {
        "home": Key(HomeInfo, writers=["get_home"]),
        "todo": Key(list[DoorwaySpec], writers=["get_home", "go"]),
        "door": Key(DoorwaySpec, writers=["go"]),
        "sides": Key(list[DoorCheckPose], writers=["go", "check"]),
        "doors": Key(dict[str, dict], default={}, writers=["check", "skip"]),
    }

    def build(self):
        visit = Sequence("visit", [Step(self.go), Step(self.check)])
        fsm = FSM("door-audit", initial="get_home")
        fsm.add_state("get_home", Step(self.get_home))
        fsm.add_state("visit", visit)
        fsm.add_state("skip", Step(self.skip))
        fsm.add_state("report", Step(self.finish), final=True)
        for state in ("get_home", "visit", "skip"):
            fsm.add_transition(state, "visit", when=lambda m, o: bool(m["todo"]))
            fsm.add_transition(state, "report")
        fsm.add_transition("visit", "skip", on_error=True)  # a door out of reach: said, then the next
        return fsm

    async def get_home(self, memory):
        self.bb.home = await self.platform.home_get_info(home_id=self.params["home"])
        room = self.params["room"]
        self.bb.todo = [d for d in self.bb.home.doors if d.checks and (not room or room in d.rooms)]
        self.log.info("%d doors to check%s", len(self.bb.todo), f" of the {room}" if room else "")

    async def go(self, memory):
        """To the nearest door left, at its check pose in the robot's room (else the nearer one): the
        other side is kept for a second look. Short walks: odometry drifts with the distance."""
        here = await self.robot.get_global_pose()
        room = self.room_of(here)

        def order(c: DoorCheckPose):
            return c.room != room, math.hypot(c.stand.x - here.x, c.stand.y - here.y)

        door = min(self.bb.todo, key=lambda d: min(order(c) for c in d.checks))
        self.bb.door, self.bb.todo = door, [d for d in self.bb.todo if d.id != door.id]
        self.bb.sides = sorted(door.checks, key=order)
        await self.walk_to(self.bb.sides[0])

    async def walk_to(self, pose: DoorCheckPose):
        """Plan and walk in legs of at most LEG_M, localizing after each (odometry drifts with the
        distance: a NAO walking 6 m ends up ~0.5 m off), then localize at the stand and step onto it."""
        done = len(self.bb.doors)
        total = done + len(self.bb.todo) + 1

        def walking(p):
            self.progress((done + (p.fraction or 0.0)) / total, f"to {self.bb.door.id}: {p.text}")

        for _ in range(8):
            plan = await self.platform.path_planning_plan_path_2d(
                map_id=self.bb.home.map_id, robot_type=self.robot_info.robot_type,
                start=await self.robot.get_global_pose(), goal=pose.stand)
            if not plan.path:
                raise RuntimeError(f"no path to door {self.bb.door.id} ({pose.side} side): {plan.reason}")
            leg, _ = first_leg(plan.path, LEG_M)
            try:
                await self.robot.move_along_path(poses=leg, _timeout=600.0, _feedback=walking)
            except RequestFailed as e:
                if e.code != ErrorCode.BLOCKED:
                    raise
                # the Core backed off where its safety kept stopping the robot (a pose that drifted
                # towards a door frame, a leaf the map does not show): localize, plan another way
                self.log.warning("blocked on the way to %s (%s): planning again", self.bb.door.id, e.reason)
                await self.localize(self.room_of(await self.robot.get_global_pose()))
                continue
            if len(leg) == len(plan.path):
                break
            await self.localize(self.room_of(leg[-1]))
        else:  # blocked or walking every time: said in the report (the FSM's skip state)
            raise RuntimeError(f"could not reach door {self.bb.door.id} ({pose.side} side) in 8 plans")
        if await self.localize(pose.room):
            await self.step_onto(pose)

    def room_of(self, p) -> str | None:
        return next((r.name for r in self.bb.home.rooms
                     if r.rect[0] <= p.x <= r.rect[2] and r.rect[1] <= p.y <= r.rect[3]), None)

    async def localize(self, room: str | None) -> bool:
        """Correct the pose estimate from the nearest landmarks facing the robot (two fixes, from at
        most four looks); False when none was decoded."""
        here = await self.robot.get_global_pose()
        marks = self.bb.home.landmarks

        def facing(m):
            dx, dy = here.x - m.x, here.y - m.y
            d = math.hypot(dx, dy)
            return d < MAX_CODE_M and (math.cos(m.yaw) * dx + math.sin(m.yaw) * dy) > 0.3 * d

        near = sorted((t for t, m in marks.items() if facing(m) and m.room in (None, room)),
                      key=lambda t: math.hypot(marks[t].x - here.x, marks[t].y - here.y))[:4]
        camera = intrinsics(await self.robot.get_camera_info(resolution=LOCALIZE_RESOLUTION))
        fixes = []
        for text in near:
            if len(fixes) == 2:
                break
            m = marks[text]
            await self.robot.look_at_point(x=m.x, y=m.y, z=m.z)
            image = await self.robot.capture_image(resolution=LOCALIZE_RESOLUTION)
            found = await self.platform.qr_detection(image_b64=image.data_b64, camera=camera, code_size_m=m.size_m)
            seen = [MarkerObservation(text=c.text, pose_in_camera=c.pose_in_camera) for c in found.codes
                    if c.pose_in_camera and c.text in marks and marks[c.text].size_m == m.size_m]
            if seen:
                mount = await self.robot.get_transform(chain="camera", space="robot")
                fixes.append(await self.platform.compute_global_pose(
                    observations=seen, camera_to_robot=mount.matrix,
                    landmarks={o.text: marks[o.text] for o in seen}))
        if not fixes:
            self.log.warning("no landmark decoded on the way to %s: going on with the odometry's pose", self.bb.door.id)
            return False
        x, y = sum(f.x for f in fixes) / len(fixes), sum(f.y for f in fixes) / len(fixes)
        theta = math.atan2(sum(math.sin(f.theta) for f in fixes), sum(math.cos(f.theta) for f in fixes))
        self.log.info("localized by %d codes: (%.2f, %.2f) was (%.2f, %.2f)", len(fixes), x, y, here.x, here.y)
        await self.robot.set_global_pose(x=x, y=y, theta=theta)
        return True

    async def step_onto(self, pose: DoorCheckPose):
        here = await self.robot.get_global_pose()
        if math.hypot(pose.stand.x - here.x, pose.stand.y - here.y) > 0.05 or \
                abs(math.remainder(pose.stand.theta - here.theta, math.tau)) > 0.1:
            await self.robot.move_along_path(poses=[here, pose.stand], _timeout=120.0)

    async def check(self, memory):
        door, side = self.bb.door, self.bb.sides[0]
        reply = await check_door(self, door)
        if reply.confidence < float(self.params["min_confidence"]) and len(self.bb.sides) > 1:
            self.log.info("door %s: confidence %.2f, looking again from the %s side", door.id, reply.confidence,
                          self.bb.sides[1].side)
            self.bb.sides = self.bb.sides[1:]
            side = self.bb.sides[0]
            await self.walk_to(side)
            reply = await check_door(self, door)
        is_open = reply.door_angle > float(self.params["open_deg"])
        row = {"open": is_open, "angle_deg": round(reply.door_angle, 1), "confidence": round(reply.confidence, 2),
               "side": side.side}
        self.bb.doors = {**self.bb.doors, door.id: row}
        if side.side == "swing":  # beside the open leaf's line: step back from it before walking on
            await self.robot.move_to(x=-0.5)
        await self.report(f"Door {door.id}: {'open' if is_open else 'closed'} ({reply.door_angle:.0f} degrees)",
                          door=door.id, **row)

    async def skip(self, memory):
        reason = self.root.last_outcome.reason
        self.bb.doors = {**self.bb.doors, self.bb.door.id: {"open": None, "reason": reason}}
        await self.report(f"Door {self.bb.door.id}: not checked ({reason})")

    async def finish(self, memory):
        doors = self.bb.doors
        opened = sorted(d for d, r in doors.items() if r["open"])
        self.progress(1.0, "done")
        await self.report(f"{len(doors)} doors checked; open: {', '.join(opened) or 'none'}", doors=doors)
