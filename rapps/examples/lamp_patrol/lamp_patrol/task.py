"""Lamp patrol: for each lamp of the home, go there, look, check the light, keep the picture."""
import base64

from ontology.services.home import HazardSpec, HomeInfo
from rapps.sdk import FSM, Key, Retry, Sequence, Step, Task
from rapps.sdk.paths import cut_path, path_length


class LampPatrol(Task):
    keys = {  # the typed blackboard: every key, its type and the states that write it
        "home": Key(HomeInfo, writers=["get_home"]),
        "todo": Key(list[HazardSpec], writers=["get_home", "go"]),
        "lamp": Key(HazardSpec, writers=["go"]),
        "found": Key(dict[str, bool], default={}, writers=["check"]),
    }

    def build(self):
        visit = Sequence("visit", [Step(self.go), Retry(Step(self.look), attempts=2), Step(self.check)])
        fsm = FSM("lamp-patrol", initial="get_home")
        fsm.add_state("get_home", Step(self.get_home))
        fsm.add_state("visit", visit)
        fsm.add_state("report", Step(self.finish), final=True)
        fsm.add_transition("get_home", "visit", when=lambda m, o: bool(m["todo"]))
        fsm.add_transition("get_home", "report")
        fsm.add_transition("visit", "visit", when=lambda m, o: bool(m["todo"]))
        fsm.add_transition("visit", "report")
        fsm.add_transition("visit", "skip", on_error=True)  # a lamp out of reach: said, then the next
        fsm.add_state("skip", Step(self.skip))
        fsm.add_transition("skip", "visit", when=lambda m, o: bool(m["todo"]))
        fsm.add_transition("skip", "report")
        return fsm

    async def get_home(self, memory):
        self.bb.home = await self.platform.home_get_info(home_id=self.params["home"])
        room = self.params["room"]
        lamps = [h for h in self.bb.home.hazards if h.type == "lamp" and (not room or h.room == room)]
        self.bb.todo = lamps
        self.log.info("%d lamps to check%s", len(lamps), f" in the {room}" if room else "")

    async def go(self, memory):
        self.bb.lamp, self.bb.todo = self.bb.todo[0], self.bb.todo[1:]
        done, total = len(self.bb.found), len(self.bb.found) + len(self.bb.todo) + 1
        def walking(p):  # the motion's progress informs (an action with feedback): shown live
            self.progress((done + (p.fraction or 0.0)) / total, f"to {self.bb.lamp.id}: {p.text}")

        while True:  # odometry drifts: localize, plan from there, walk one leg; again until at the lamp
            here = await self.localize()  # by the home's QR codes: the pose and its uncertainty
            self.log.info("at (%.2f, %.2f) +- %.3f m", here.x, here.y, here.std_m)
            plan = await self.platform.path_planning_plan_path_2d(
                map_id=self.bb.home.map_id, robot_type=self.robot_info.robot_type, start=here.pose,
                goal=self.bb.lamp.stand)
            if not plan.path:
                raise RuntimeError(f"no path to {self.bb.lamp.id}: {plan.reason}")  # the Sequence fails: skipped
            # as far as the pose filter expects to stay within 5 cm of the path (1 sigma), at most leg_m
            longest = self.localizer.leg_length(float(self.params["leg_m"]), 0.05)
            await self.robot.move_along_path(poses=cut_path(plan.path, longest), _timeout=600.0, _feedback=walking)
            if path_length(plan.path) <= longest:  # the whole rest of it: there
                break
        await self.localize()  # at the lamp: the camera aims from the pose the codes give

    async def look(self, memory):
        x, y, z = self.bb.lamp.look_at
        await self.robot.look_at_point(x=x, y=y, z=z)

    async def check(self, memory):
        image = await self.robot.capture_image(resolution="640x480")
        level = await self.platform.hazard_detection_light_check(image_b64=image.data_b64)
        (self.outputs / f"{self.bb.lamp.id}.png").write_bytes(base64.b64decode(image.data_b64))
        self.bb.found = {**self.bb.found, self.bb.lamp.id: level.lamp_on}
        await self.report(f"Lamp {self.bb.lamp.id}: {'on' if level.lamp_on else 'off'}",
                          lamp=self.bb.lamp.id, on=level.lamp_on, level=level.light_level,
                          stand=[self.bb.lamp.stand.x, self.bb.lamp.stand.y])  # where it meant to stand

    async def skip(self, memory):
        self.log.warning("lamp %s not checked: %s", self.bb.lamp.id, self.root.last_outcome.reason)
        await self.report(f"Lamp {self.bb.lamp.id}: not checked ({self.root.last_outcome.reason})")

    async def finish(self, memory):
        on = sorted(k for k, v in self.bb.found.items() if v)
        self.progress(1.0, "done")
        await self.report(f"{len(self.bb.found)} lamps checked; on: {', '.join(on) or 'none'}", lamps=self.bb.found,
                          localization=self.localizer.stats())
