"""The Core's own pose estimate (paper 001: relativeLocalization and computeCurrentPose are a_core's): the
robot's odometry followed by a pose EKF (agents/pose_ekf.py, the SDK's filter), fused with the global fixes a
RApp hands it, served to the supervising RApp as robot actions with their covariance:

    get_pose_estimate          the estimate now: pose, 3x3 covariance, how many fixes it holds
    add_pose_fix               a global fix (x, y, theta with standard deviations): fused unless too far
                               from the estimate for both uncertainties (chi-square, 99 %); answers the estimate

Where the fixes come from: the RApp. In paper 001 (fig. 6) the global localization is the RApp's: a_dyn
captures images through a_core, a_cloud's qrCodeDetection finds the codes, a_dyn's computeGlobalPose turns
them into a pose with the marker map; the Core's part is the relative localization and the current pose
from both. So the Core does not look for QR codes on its own camera frames (it would also fight the task for
the camera and the head): it accepts the fixes a RApp sends with add_pose_fix (the SDK's Task.localize
keeps its own filter and sends the Core each fix it takes), and follows the odometry between them.

The robot's odometry is read every SAMPLE_S (wall clock) from the Core's start, with its counters of the
motion made (RobotInterface.odometry_counters): the estimate's uncertainty grows with the metres and radians
counted between two reads, not with the displacement alone, so a read that spans several legs (a world run
many times faster than real time, or a turn and back) is as uncertain as the legs. A RApp's set_global_pose
resets that odometry (it is the robot's own estimate), so the Core takes the motion up to it, then follows
the odometry from the pose set: a set pose is not a fix (it carries no uncertainty). The start is the
odometry's pose when the Core starts, hardly trusted (START_STD_M, START_STD_RAD). The odometry's error
model is the robot type's (ontology/robot_types.py), as the SDK's filter uses.
"""
from __future__ import annotations

import asyncio
import logging
from typing import Any, Awaitable, Callable

from ontology.robot import AddPoseFix, GetGlobalPose, PoseEstimate, SetGlobalPose
from ontology.services.common import Pose2D

from .pose_ekf import CHI2_3DOF_99, ODOMETRY, PoseEKF, wrap

log = logging.getLogger("rapp.core")
SAMPLE_S = 0.1
START_STD_M, START_STD_RAD = 0.5, 0.3


class CoreLocalizer:
    def __init__(self, robot, robot_type: str):
        self.robot = robot
        self.model = ODOMETRY[robot_type] if robot_type in ODOMETRY else ODOMETRY["nao"]  # unknown: the most generous
        self.ekf: PoseEKF | None = None
        self.odom: tuple[float, float, float] | None = None  # the odometry's pose at the last sample
        self.counted = (0.0, 0.0)  # the odometry's counters then (m travelled, rad turned)
        self.fixes = 0
        self._lock = asyncio.Lock()
        self._task: asyncio.Task | None = None

    def start(self) -> None:
        """Follow the odometry from now (an asyncio task of the Core's loop)."""
        if self._task is None:
            self._task = asyncio.create_task(self._follow(), name="core-localizer")

    async def stop(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    async def _follow(self) -> None:
        failures = 0
        while True:
            try:
                async with self._lock:
                    await self._sample()
            except Exception as e:  # noqa: BLE001 - a failed read (robot shutting down): the next one tries again
                failures += 1
                log.log(logging.WARNING if failures == 1 else logging.DEBUG, "localizer: no odometry: %s", e)
            await asyncio.sleep(SAMPLE_S)

    async def read(self) -> None:
        """Follow the odometry up to now: the Core's command server calls it as a base motion starts and
        ends, so each leg is predicted on its own whatever the wall clock's sampling caught of it."""
        try:
            async with self._lock:
                await self._sample()
        except Exception as e:  # noqa: BLE001 - as a sample of _follow: the next read takes the motion along
            log.debug("localizer: no odometry: %s", e)

    async def _sample(self) -> PoseEKF:
        pose = await self.robot.handle(GetGlobalPose())
        counted = self.robot.odometry_counters()
        odom = (pose.x, pose.y, pose.theta)
        if self.ekf is None or self.odom is None:
            self.ekf, self.odom = PoseEKF(odom, START_STD_M, START_STD_RAD), odom
        elif odom != self.odom or counted != self.counted:
            travelled, turned = (max(now - before, 0.0) for now, before in zip(counted, self.counted))
            self.ekf.predict_between(self.odom, odom, self.model, travelled_m=travelled, turned_rad=turned)
            self.odom = odom
        self.counted = counted
        return self.ekf

    async def handle(self, req) -> PoseEstimate:
        """get_pose_estimate or add_pose_fix."""
        async with self._lock:
            ekf = await self._sample()
            if not isinstance(req, AddPoseFix):
                return self.estimate(ekf)
            accepted = ekf.update((req.x, req.y, req.theta), std_m=req.std_m, std_rad=req.std_rad,
                                  gate=CHI2_3DOF_99 if req.gate else None)
            self.fixes += accepted
            return self.estimate(ekf, accepted)

    async def set_global_pose(self, req: SetGlobalPose, forward: Callable[[Any], Awaitable[Any]]) -> Any:
        """The robot's odometry is set: the motion before counts, then it is followed from the pose set."""
        async with self._lock:
            try:
                await self._sample()
            except Exception as e:  # noqa: BLE001 - the pose is set all the same
                log.debug("localizer: no odometry before set_global_pose: %s", e)
            reply = await forward(req)
            self.odom = (req.x, req.y, wrap(req.theta))
            return reply

    def estimate(self, ekf: PoseEKF, accepted: bool = True) -> PoseEstimate:
        x, y, th = ekf.pose
        return PoseEstimate(pose=Pose2D(x=x, y=y, theta=th), covariance=ekf.P.tolist(), std_m=ekf.std_m,
                            std_rad=ekf.std_rad, fixes=self.fixes, accepted=accepted)
