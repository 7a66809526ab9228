"""Self-localization sub-FSM (fig. 16 s2): capture, find QR landmarks on the Cloud Agent and solve the
pose from every code seen so far; while that pose is not certain enough turn the head one step and try
again until the head limit, then once more with the body turned half round; then set the pose on the
robot (the odometry estimate stays if the pose is still too uncertain)."""
from __future__ import annotations

import functools
import math

from rapps.sdk import FSM, RequestError, RequestFailed, Step

# head joints, sweep limit (rad) and the pitch to look at landmarks at 0.7 m (positive = down), per robot model
HEADS = {
    "HeadYaw": {"yaw": "HeadYaw", "pitch": "HeadPitch", "limit": 2.0, "tilt": -0.12},  # camera ~0.5 m: look up
    "HeadPan": {"yaw": "HeadPan", "pitch": "HeadTilt", "limit": 2.7, "tilt": 0.12},
}


def sweep_angles(step: float, limit: float) -> list[float]:
    """0, +s, -s, +2s, -2s, ... within the head limit."""
    out, k = [0.0], 1
    while k * step <= limit + 1e-9:
        out += [k * step, -k * step]
        k += 1
    return out


def noting_failure(step):
    """A localization step that, when a request fails, leaves why in memory["error"]: a hazard the
    robot was walking to is then reported unreachable with it (task.unreachable)."""

    @functools.wraps(step)
    async def run(self, memory):
        try:
            return await step(self, memory)
        except RequestError as e:
            memory["error"] = f"(localization failed: {e.reason})"
            raise

    return run


class Localizer:
    """Builds the localization sub-FSM of a task; results land in memory["localization"]."""

    def __init__(self, task):
        self.task = task
        self.head: dict | None = None
        self.camera = None

    def build(self, name: str = "localize") -> FSM:
        fsm = FSM(name, initial="l1_prepare")
        fsm.add_state("l1_prepare", Step(self.prepare))
        fsm.add_state("l2_turn_head", Step(self.turn_head))
        fsm.add_state("l3_capture", Step(self.capture))
        fsm.add_state("l4_detect", Step(self.detect))
        fsm.add_state("l5_set_pose", Step(self.set_pose), final=True)
        fsm.add_state("l6_turn_around", Step(self.turn_around))
        fsm.add_transition("l1_prepare", "l2_turn_head")
        fsm.add_transition("l2_turn_head", "l3_capture", when=lambda m, o: o.value)
        # head limit: look behind once (the body turns half round), then give up
        fsm.add_transition("l2_turn_head", "l6_turn_around", when=lambda m, o: not o.value and not m["looked_behind"])
        fsm.add_transition("l2_turn_head", "l5_set_pose", when=lambda m, o: not o.value and m["looked_behind"])
        fsm.add_transition("l6_turn_around", "l2_turn_head")
        fsm.add_transition("l3_capture", "l4_detect")
        fsm.add_transition("l4_detect", "l5_set_pose", when=lambda m, o: o.value)
        fsm.add_transition("l4_detect", "l2_turn_head", when=lambda m, o: not o.value)
        return fsm

    @noting_failure
    async def prepare(self, memory):
        robot, params = self.task.robot, self.task.params
        if self.head is None:
            names = (await robot.get_joint_angles()).joints
            self.head = next(h for key, h in HEADS.items() if key in names)
            info = await robot.get_camera_info(resolution=params["localize_resolution"])
            K = info.K
            self.camera = dict(fx=K[0][0], fy=K[1][1], cx=K[0][2], cy=K[1][2])
        memory["sweep"] = sweep_angles(float(params["head_step_rad"]), self.head["limit"])
        memory["observations"] = []
        memory["localization"] = memory["prior"] = None
        memory["looked_behind"] = not params.get("look_behind", True)

    @noting_failure
    async def turn_around(self, memory):
        """No certain pose within the head's reach: turn the body half round and sweep again (codes
        seen before the turn are dropped: their camera-to-robot transforms no longer hold)."""
        memory["looked_behind"] = True
        await self.task.robot.move_to(x=0.0, y=0.0, theta=math.pi, _timeout=60.0)
        memory["sweep"] = sweep_angles(float(self.task.params["head_step_rad"]), self.head["limit"])
        memory["observations"] = []
        memory["localization"] = memory["prior"] = None

    @noting_failure
    async def turn_head(self, memory) -> bool:
        """Next head position of the sweep; False when the head limit is reached."""
        if not memory["sweep"]:
            return False
        yaw = memory["sweep"].pop(0)
        await self.task.robot.move_joint(joints=[self.head["yaw"], self.head["pitch"]],
                                         angles=[yaw, self.head["tilt"]], speed=0.8)
        return True

    @noting_failure
    async def capture(self, memory):
        robot = self.task.robot
        memory["frame"] = await robot.capture_image(resolution=self.task.params["localize_resolution"])
        memory["camera_to_robot"] = (await robot.get_transform(chain="camera", space="robot")).matrix

    @noting_failure
    async def detect(self, memory) -> bool:
        """Landmarks in this frame (on the Cloud Agent), then the pose from every code seen so far;
        True when that pose is certain enough to stop sweeping (its position standard deviation at
        most localize_std_m: two codes close together or far away are not enough)."""
        try:
            reply = await self.task.cloud.call(
                "observe", image_b64=memory.pop("frame").data_b64, camera=self.camera,
                camera_to_robot=memory["camera_to_robot"], landmarks=memory["home"].landmarks,
                max_distance_m=float(self.task.params["max_marker_distance_m"]))
        except RequestFailed:  # a frame the Cloud Agent could not process: look elsewhere
            return False
        if not reply.items:
            return False
        memory["observations"].extend(reply.items)
        if memory.get("prior") is None:
            memory["prior"] = await self.task.robot.get_global_pose()
        found = await self.task.cloud.call("solve_pose", observations=memory["observations"],
                                           landmarks=memory["home"].landmarks, prior=memory["prior"].model_dump())
        memory["localization"] = found
        return self._certain(found, "localize_std_m", "localize_std_rad")

    def _certain(self, found, param_m: str, param_rad: str) -> bool:
        """Position and heading certain enough: a heading off by 0.01 rad puts the end of a 1 m leg
        1 cm off the path."""
        params = self.task.params
        return bool(found.found and found.std_m is not None and found.std_theta_rad is not None
                    and found.std_m <= float(params[param_m]) and found.std_theta_rad <= float(params[param_rad]))

    @noting_failure
    async def set_pose(self, memory):
        """Set the sweep's pose on the robot if it is certain enough (localize_max_std_m); otherwise
        the odometry estimate stays."""
        found = memory.get("localization")
        if found is not None and self._certain(found, "localize_max_std_m", "localize_max_std_rad"):
            p = found.pose
            await self.task.robot.set_global_pose(x=p.x, y=p.y, theta=p.theta)
            memory.setdefault("localizations", []).append(
                {"x": p.x, "y": p.y, "theta": p.theta, "markers": found.markers, "method": found.method,
                 "std_m": found.std_m})
        else:
            memory.setdefault("localizations", []).append(None)
        await self._head_home()

    async def _head_home(self):
        await self.task.robot.move_joint(joints=[self.head["yaw"], self.head["pitch"]], angles=[0.0, 0.0],
                                         speed=0.8)


