"""Self-localization sub-FSM (fig. 16 s2): capture, find QR landmarks on the Cloud Agent and solve the
pose from every code seen so far; while that pose is not certain enough turn the head one step and try
again until the head limit, then once more with the body turned half round; then fuse the fix into the
pose EKF (paper 001: QR-code global localization with EKF relative localization) and set the filter's
pose on the robot.

The EKF (rapps/sdk/ekf.py) predicts from the robot's odometry between fixes, so it knows how uncertain
the pose has become: a certain fix replaces the pose almost entirely, a less certain one (too few or too
far codes) is weighed against the odometry instead of being thrown away, and one that disagrees with
the prediction beyond chance is refused. Its covariance also tells the task how long the next leg may
be (`leg_length`)."""
from __future__ import annotations

import functools
import math

from rapps.sdk import FSM, RequestError, RequestFailed, Step
from rapps.sdk.ekf import CHI2_3DOF_99, ODOMETRY, OdometryModel, PoseEKF

# head joints, sweep limit (rad) and the pitch to look at landmarks at 0.7 m (positive = down), per robot model
HEADS = {
    "HeadYaw": {"yaw": "HeadYaw", "pitch": "HeadPitch", "limit": 2.0, "tilt": -0.12},  # camera ~0.5 m: look up
    "HeadPan": {"yaw": "HeadPan", "pitch": "HeadTilt", "limit": 2.7, "tilt": 0.12},
}


START_STD_M, START_STD_RAD = 0.5, 0.3  # the start pose the robot was given is hardly trusted
# a fix's standard deviations come from the corners' pixel noise only; the camera's pose on the robot,
# the printed codes and the map add their own: never trust a fix more than this
FIX_FLOOR_M, FIX_FLOOR_RAD = 0.004, 0.002
FUSE_MAX_STD_M, FUSE_MAX_STD_RAD = 0.10, 0.05  # a fix less certain than this is no fix at all


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
        self.ekf: PoseEKF | None = None
        self.odom_ref: tuple[float, float, float] | None = None  # the robot's odometry pose the filter matched last
        self.travelled = self.turned = 0.0  # motion since then (m, rad), as commanded

    # -- the pose filter ---------------------------------------------------------------------
    def odometry_model(self) -> OdometryModel:
        return ODOMETRY.get(self.task.robot_type(), ODOMETRY["nao"])

    def moved(self, distance: float = 0.0, rotation: float = 0.0) -> None:
        """The task moved the base (m driven, rad turned): the odometry error grows with it."""
        self.travelled += abs(distance)
        self.turned += abs(rotation)

    async def track(self) -> PoseEKF:
        """Bring the filter up to the robot's odometry now (the first time: start it there)."""
        p = await self.task.robot.get_global_pose()
        odom = (p.x, p.y, p.theta)
        if self.ekf is None:
            self.ekf = PoseEKF(odom, START_STD_M, START_STD_RAD)
        else:
            self.ekf.predict_between(self.odom_ref, odom, self.odometry_model(), travelled_m=self.travelled,
                                     turned_rad=self.turned)
        self.odom_ref, self.travelled, self.turned = odom, 0.0, 0.0
        return self.ekf

    def position_std(self) -> float:
        """The pose filter's position std (m) now; 0 before it starts (the plan monitor's "localized")."""
        return self.ekf.std_m if self.ekf is not None else 0.0

    def leg_length(self, longest: float, cross_track_std_m: float, shortest: float = 0.3) -> float:
        """The longest leg (at most `longest`) whose predicted sideways error stays within
        `cross_track_std_m` (one sigma) by the filter's covariance and the odometry's error model."""
        ekf, model = self.ekf, self.odometry_model()
        if ekf is None or ekf.cross_track_std(longest, model) <= cross_track_std_m:
            return longest
        lo, hi = shortest, longest
        for _ in range(20):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if ekf.cross_track_std(mid, model) <= cross_track_std_m else (lo, mid)
        return lo

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
        await self.track()

    @noting_failure
    async def turn_around(self, memory):
        """No certain pose within the head's reach: turn the body half round and sweep again (codes
        seen before the turn are dropped: their camera-to-robot transforms no longer hold)."""
        memory["looked_behind"] = True
        await self.task.robot.move_to(x=0.0, y=0.0, theta=math.pi, _timeout=60.0)
        self.moved(rotation=math.pi)
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
        """Fuse the sweep's fix into the filter and set the filter's pose on the robot. A fix certain
        enough (localize_max_std_m/rad) is always taken; a less certain one only while it agrees with
        the prediction (Mahalanobis gate); without a fix the odometry estimate stays."""
        ekf = await self.track()
        found = memory.get("localization")
        entry = None
        if found is not None and found.found and found.std_m is not None and found.std_theta_rad is not None:
            certain = self._certain(found, "localize_max_std_m", "localize_max_std_rad")
            usable = found.std_m <= FUSE_MAX_STD_M and found.std_theta_rad <= FUSE_MAX_STD_RAD
            p = found.pose
            if (certain or usable) and ekf.update((p.x, p.y, p.theta), std_m=max(found.std_m, FIX_FLOOR_M),
                                                  std_rad=max(found.std_theta_rad, FIX_FLOOR_RAD),
                                                  gate=None if certain else CHI2_3DOF_99):
                x, y, theta = ekf.pose
                await self.task.robot.set_global_pose(x=x, y=y, theta=theta)
                self.odom_ref = ekf.pose
                entry = {"x": x, "y": y, "theta": theta, "markers": found.markers, "method": found.method,
                         "fix_std_m": found.std_m, "std_m": ekf.std_m, "std_rad": ekf.std_rad, "certain": certain}
        memory.setdefault("localizations", []).append(entry)
        await self._head_home()

    async def _head_home(self):
        await self.task.robot.move_joint(joints=[self.head["yaw"], self.head["pitch"]], angles=[0.0, 0.0],
                                         speed=0.8)


