"""Self-localization sub-FSM (fig. 16 s2): capture, find a QR landmark on the Cloud Agent; if none
is seen turn the head one step and try again until the head limit; then set the global pose."""
from __future__ import annotations



from behaviours import FSM
from rapps.sdk import Step

# head joints, sweep limit (rad) and the pitch to look at landmarks at 0.7 m, per robot model
HEADS = {
    "HeadYaw": {"yaw": "HeadYaw", "pitch": "HeadPitch", "limit": 2.0, "tilt": 0.05},
    "HeadPan": {"yaw": "HeadPan", "pitch": "HeadTilt", "limit": 2.7, "tilt": 0.12},
}


def sweep_angles(step: float, limit: float) -> list[float]:
    """0, +s, -s, +2s, -2s, ... within the head limit."""
    out, k = [0.0], 1
    while k * step <= limit + 1e-9:
        out += [k * step, -k * step]
        k += 1
    return out


class Localizer:
    """Builds the localization sub-FSM of a task; results land in memory["localization"]."""

    def __init__(self, task):
        self.task = task
        self.head: dict | None = None
        self.camera = None

    def build(self, name: str = "localize") -> FSM:
        fsm = FSM(name, initial="l1_prepare")
        fsm.add_state("l1_prepare", Step(self.prepare))
        fsm.add_state("l2_capture", Step(self.capture))
        fsm.add_state("l3_detect", Step(self.detect))
        fsm.add_state("l4_turn_head", Step(self.turn_head))
        fsm.add_state("l5_set_pose", Step(self.set_pose), final=True)
        fsm.add_state("l6_not_found", Step(self.not_found), final=True)
        fsm.add_transition("l1_prepare", "l4_turn_head")
        fsm.add_transition("l4_turn_head", "l2_capture", when=lambda m, o: o.value)
        fsm.add_transition("l4_turn_head", "l6_not_found", when=lambda m, o: not o.value)
        fsm.add_transition("l2_capture", "l3_detect")
        fsm.add_transition("l3_detect", "l5_set_pose", when=lambda m, o: o.value)
        fsm.add_transition("l3_detect", "l4_turn_head", when=lambda m, o: not o.value)
        return fsm

    async def prepare(self, memory):
        robot, params = self.task.robot, self.task.params
        if self.head is None:
            names = (await robot.get_joint_angles()).joints
            self.head = next(h for key, h in HEADS.items() if key in names)
            info = await robot.get_camera_info(resolution=params["localize_resolution"])
            K = info.K
            self.camera = dict(fx=K[0][0], fy=K[1][1], cx=K[0][2], cy=K[1][2])
        memory["sweep"] = sweep_angles(float(params["head_step_rad"]), self.head["limit"])
        memory["localization"] = None

    async def turn_head(self, memory) -> bool:
        if not memory["sweep"]:
            return False
        yaw = memory["sweep"].pop(0)
        await self.task.robot.move_joint(joints=[self.head["yaw"], self.head["pitch"]],
                                         angles=[yaw, self.head["tilt"]], speed=0.8)
        return True

    async def capture(self, memory):
        robot = self.task.robot
        memory["frame"] = await robot.capture_image(resolution=self.task.params["localize_resolution"])
        memory["camera_to_robot"] = (await robot.get_transform(chain="camera", space="robot")).matrix

    async def detect(self, memory) -> bool:
        info = memory["home"]
        reply = await self.task.cloud.call(
            "localize", image_b64=memory.pop("frame").data_b64, camera=self.camera,
            camera_to_robot=memory["camera_to_robot"], landmarks=info.landmarks,
            max_distance_m=float(self.task.params["max_marker_distance_m"]))
        memory["localization"] = reply
        return reply.found

    async def set_pose(self, memory):
        p = memory["localization"].pose
        await self.task.robot.set_global_pose(x=p.x, y=p.y, theta=p.theta)
        memory.setdefault("localizations", []).append(
            {"x": p.x, "y": p.y, "theta": p.theta, "markers": memory["localization"].markers})
        await self._head_home()

    async def not_found(self, memory):
        memory.setdefault("localizations", []).append(None)
        await self._head_home()

    async def _head_home(self):
        await self.task.robot.move_joint(joints=[self.head["yaw"], self.head["pitch"]], angles=[0.0, 0.0],
                                         speed=0.8)


