"""The Core Agent's robot-API server (paper 000 fig. 5, s8/s9; the emergency stop of paper 003)."""
from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

import ontology.robot  # also registers the robot-API models the command server serves
from ontology.registry import Progress, actions
from ontology.robot_actions import facts, resumable
from ontology import core as C
from ontology.errors import ErrorCode
from ontology.notifications import EventTopic
from ontology.trace import StructureEvent
from robots.errors import MotionBlocked, MotionInterrupted, RobotError

from .base import RESEND_EVERY_S
from .errors import Failure, Refusal
from .core_events import ESTOP_TTL_S
from .core_fsm import build_command_fsm
from .core_parts import AHEAD_RAD, CommandsHost, ObstacleEcho
from .locks import LockError, ResourceLocks, device_of
from .passes import run_pass
from .messages import bare
from .responder import Responder

if TYPE_CHECKING:
    from .core_localizer import CoreLocalizer

log = logging.getLogger("rapp.core")
FEEDBACK_EVERY_S = 0.5


def path_progress(path: list[tuple[float, float]], x: float, y: float) -> float:
    """Fraction (0..1) of a polyline's length before the point of it nearest to (x, y)."""
    lengths = [math.dist(a, b) for a, b in zip(path, path[1:])]
    total = sum(lengths) or 1.0
    best, before = (math.inf, 0.0), 0.0
    for (a, b), seg in zip(zip(path, path[1:]), lengths):
        t = 0.0 if seg == 0 else max(0.0, min(1.0, ((x - a[0]) * (b[0] - a[0]) + (y - a[1]) * (b[1] - a[1])) / seg ** 2))
        d = math.dist((x, y), (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])))
        if d < best[0]:
            best = (d, before + t * seg)
        before += seg
    return max(0.0, min(1.0, best[1] / total))


SONAR_BEARING_RAD = 0.44  # a NAO sonar looks 25° to its side (robots/nao.py), when the reading does not say


Publish = Callable[..., Awaitable[Any]]  # CoreEvents.publish(topic, ttl_s, **data)


class RobotCommands:
    """The Core's robot-API server, a member of the CoreAgent (`core.robot_commands`): while a
    Dynamic Agent supervises, the "command-server" behaviour (`service()`) executes its robot-API
    requests on the robot.

    - supervisor-only commands: a request is served only for the current, not yet ended Dynamic
      Agent, and only in the robot-API groups its manifest declares (`_only_supervisor`);
    - per-action facts (device, motion, effect on a velocity) come from ontology/robot_actions.py;
    - resource locks: each command takes the lock of its device (agents/locks.py); the Dynamic
      Agent may also lock and free resources itself (lock_resource / free_resource);
    - the e-stop latch: `emergency_stop()` halts every effector and holds the task's motions until
      `resume_motion()` (then re-issues those it interrupted when their target is absolute);
    - the safety check: `nearest_obstacle()` (read by core_behaviours.SafetyMonitor) and whether
      the base is being driven (`driving`); a task's motion the robot's own collision protection
      stopped (MotionBlocked, RobotInterface.protect) latches the same safety stop when its target is
      absolute: `on_safety_stop` (the reactive strategies, agents/core_strategies.py) then hands it
      back or fails it (`blocked`).

    What it needs of the Core is `CommandsHost` (agents/core_parts.py); `publish` tells the task's
    subscribers of the e-stop (CoreEvents.publish).
    """

    def __init__(self, host: CommandsHost, publish: Publish, safety_distance: float | None = 0.10):
        self.host, self.publish = host, publish
        self.locks = ResourceLocks()
        self.estop_reason: str | None = None  # set while the emergency stop is latched
        self.estop_by: str | None = None  # who latched it: "owner" or "safety"
        self._estop_released = asyncio.Event()  # set while not latched: held motions wait on it
        self._estop_released.set()
        self.fail_held: tuple[str, str] | None = None  # (code, reason): held motions fail at the release
        self.driving = False  # a move_vel velocity is in force
        self.safety_distance = safety_distance  # the safety check's margin (None: off)
        # what a safety stop of a blocked motion starts (the strategies; set by the Core)
        self.on_safety_stop: Callable[[], Awaitable[Any]] | None = None
        self.localizer: CoreLocalizer | None = None  # the Core's pose estimate (agents/core_localizer.py)

    @property
    def robot(self):
        return self.host.robot

    def service(self) -> Responder:
        handlers = {name: self._robot_call for name in actions("robot")}
        return Responder("robot", handlers, check=self._only_supervisor)

    def _only_supervisor(self, req, ctx) -> None:
        d = self.host.dynamic
        if d is None or ctx.sender != bare(d.jid) or d.ended.is_set():
            raise Refusal(f"{ctx.sender} is not the current supervisor of {self.host.robot_id}", ErrorCode.NOT_SUPERVISOR)
        if req.group != "resources" and req.group not in d.manifest.robot_api:
            raise Refusal(f"{d.rapp} did not declare the robot-API group {req.group!r} "
                          f"(needed by {req.action_name}) in its manifest", ErrorCode.PERMISSION)

    async def _robot_call(self, req, ctx):
        """s9 of fig. 5: one robot-API request of the supervising Dynamic Agent, as a pass of the
        command sub-FSM (agents/core_fsm.py build_command_fsm), side by side with its other requests
        while the Core's FSM stays in s8."""
        memory = {"request": req, "ctx": ctx, "steps": self}
        try:
            return await run_pass(self.host, build_command_fsm(req.action_name), memory, ctx.info.conversation_id)
        except LockError as e:
            raise Refusal(str(e), ErrorCode.LOCKED) from None
        finally:
            if memory.get("reporter") is not None:
                memory["reporter"].cancel()
            device = memory.pop("locked", None)  # released here whatever ended the pass
            if device is not None and self.locks.holder(device) == ctx.sender:  # (not dropped at a destroy)
                self.locks.free(device, ctx.sender)

    # -- the steps of s9 (agents/core_fsm.py) ------------------------------------------------------
    async def command_resources(self, memory: dict):
        """The Dynamic Agent's own lock and free of a resource (paper 003)."""
        req, ctx = memory["request"], memory["ctx"]
        if req.action_name == "lock_resource":
            memory["reply"] = await self._lock(req, ctx.sender)
        else:
            memory["reply"] = self._free(req, ctx.sender)

    async def command_lock(self, memory: dict) -> None:
        """The device's lock for the command (waits up to 60 s for it); a velocity's effect noted."""
        req, ctx = memory["request"], memory["ctx"]
        drive = facts(req.action_name).drive
        if drive == "sets":  # a velocity keeps the base moving after the call returns
            self.driving = any(abs(getattr(req, f, 0.0) or 0.0) > 1e-9 for f in ("x", "y", "theta"))
        elif drive == "ends":
            self.driving = False
        device = device_of(req.action_name)
        if device is not None:
            if not await self.locks.lock(device, ctx.sender, 60.0):
                raise LockError(f"{device} is busy (held by {self.locks.holder(device)})")
            memory["locked"] = device

    async def command_act(self, memory: dict):
        """Carry the command out. A motion of the task while the emergency stop is latched is held,
        not refused (the value "held": s9's held state waits for the release); one the stop
        interrupts is issued again after the resume when its target is absolute
        (robot_actions.resumable), else it fails with `estop` (a relative move would go somewhere
        else from where the stop left the robot)."""
        req, ctx = memory["request"], memory["ctx"]
        name = req.action_name
        if self.localizer is not None and (facts(name).core or name == "set_global_pose"):
            # the Core's pose estimate: served by it; a set pose resets the odometry it follows
            memory["reply"] = await (self.localizer.handle(req) if facts(name).core
                                     else self.localizer.set_global_pose(req, self.robot.handle))
            return "done"
        if not facts(name).motion:
            memory["reply"] = await self.robot.handle(req)
            return "done"
        if ctx.wants_feedback and memory.get("reporter") is None:
            memory["reporter"] = asyncio.create_task(self._report_motion(req, ctx))
        if self.estop_reason is not None:
            return "held"
        # the Core's pose estimate predicts each leg on its own: a read as it starts and as it ends
        localizer = self.localizer if facts(name).device == "base" else None
        try:
            if localizer is not None:
                await localizer.read()
            memory["reply"] = await self.robot.handle(req)  # cancelled by the requester: the motion stops
            return "done"
        except MotionBlocked as e:
            if not self.safety_distance:
                raise
            # the robot's collision protection (or its bumper) stopped it: the safety stop, as the
            # safety check's; the reactive strategies hand the held motion back or fail it (blocked).
            # The safety check may have latched it a moment before (both see the same obstacle;
            # its stop had not yet interrupted the motion): then the motion is held as interrupted
            if self.estop_reason is None:
                await self.safety_stop(f"obstacle ahead ({e})")
        except MotionInterrupted:
            if self.estop_reason is None:
                raise
        finally:
            if localizer is not None:
                await localizer.read()
        if not resumable(name):
            raise Failure(f"{name} was interrupted by the emergency stop ({self.estop_reason}); "
                          f"a relative motion is not resumed", ErrorCode.ESTOP)
        return "held"

    async def command_held(self, memory: dict) -> None:
        """A motion held by the emergency stop: told, then issued again at the release (or failed when
        a strategy hands it back with the way blocked: the task re-plans)."""
        req, ctx = memory["request"], memory["ctx"]
        name = req.action_name
        self.host.record_structure(StructureEvent.MOTION_HELD, action=name, reason=self.estop_reason)
        await ctx.feedback(Progress(text=f"held by the emergency stop ({self.estop_reason})", data={"paused": True}))
        await self._estop_released.wait()
        if self.fail_held is not None:
            code, why = self.fail_held
            raise Failure(f"{name}: {why}", code)
        self.host.record_structure(StructureEvent.MOTION_RESUMED, action=name)

    async def command_release(self, memory: dict) -> None:
        """The device's lock freed: the command is done."""
        ctx = memory["ctx"]
        device = memory.pop("locked", None)
        if device is not None:
            self.locks.free(device, ctx.sender)

    async def _report_motion(self, req, ctx) -> None:
        """Progress informs of a motion, at its start and then every FEEDBACK_EVERY_S: the estimated
        pose and, along a path, the fraction of its length behind the robot."""
        path = [(p.x, p.y) for p in getattr(req, "poses", [])]
        while True:
            pose = await self.robot.handle(ontology.robot.GetGlobalPose())
            fraction = path_progress(path, pose.x, pose.y) if len(path) > 1 else None
            text = f"at ({pose.x:.2f}, {pose.y:.2f})" + (f", {fraction:.0%} of the path" if fraction is not None else "")
            await ctx.feedback(Progress(fraction=fraction, text=text, data=pose.model_dump()))
            await asyncio.sleep(FEEDBACK_EVERY_S)

    async def _lock(self, req, owner: str):
        try:
            ok = (await self.locks.lock(req.resource, owner, req.timeout_s) if req.wait
                  else self.locks.try_lock(req.resource, owner))
        except LockError as e:
            raise Refusal(str(e), ErrorCode.UNKNOWN_RESOURCE) from None
        return ontology.robot.LockState(resource=req.resource, held=ok, holder=self.locks.holder(req.resource))

    def _free(self, req, owner: str):
        try:
            self.locks.free(req.resource, owner)
        except LockError as e:
            raise Failure(str(e), ErrorCode.NOT_HOLDER) from None
        return ontology.robot.LockState(resource=req.resource, held=False, holder=self.locks.holder(req.resource))

    # -- emergency stop (paper 003) -----------------------------------------------------------
    async def emergency_stop(self, reason: str, by: str = "owner") -> None:
        """Halt every effector now (bypassing queued commands) and latch until resumed; the Dynamic
        Agent is told (C.TaskPaused): its task pauses and its motions are held, not failed.
        `by`: who latched it ("owner" or "safety"); only the owner releases an owner's stop."""
        first = self.estop_reason is None
        taken_over = not first and by == "owner" and self.estop_by != "owner"  # the strategies let go
        self.estop_reason, self.estop_by = reason, by if first or taken_over else self.estop_by
        self.fail_held = None
        self._estop_released.clear()
        await self.stop_robot(everything=True)
        if first:
            self.host.record_structure("estop", robot=self.host.robot_id, reason=reason, by=by)
            await self._tell_task(True, reason)
            await self.publish(EventTopic.ESTOP, ESTOP_TTL_S, latched=True, reason=reason, by=by)
        if (first or taken_over) and by != "safety":  # a safety stop is told folded (core_strategies)
            d = self.host.dynamic
            task = f" or \"cancel\" to end {d.rapp}" if d is not None and not d.ended.is_set() else ""
            await self.host.tell_user(f"Emergency stop: {reason}. Say \"resume\" to let me move again{task}.")

    async def safety_stop(self, reason: str) -> None:
        """The safety latches the stop; the reactive strategies (`on_safety_stop`) then decide, in the
        background, how to hand the robot back."""
        await self.emergency_stop(reason, by="safety")
        if self.on_safety_stop is not None:
            self.host.in_background(self.on_safety_stop())

    async def resume_motion(self, by: str = "owner") -> None:
        if self.estop_reason is not None:
            quiet = self.estop_by == "safety" and by != "owner"  # a strategy's hand-back: folded
            self.estop_reason, self.estop_by = None, None
            self.host.record_structure("estop-released", robot=self.host.robot_id, by=by)
            self._estop_released.set()
            await self._tell_task(False, "resumed")
            await self.publish(EventTopic.ESTOP, ESTOP_TTL_S, latched=False, reason="resumed", by=by)
            if not quiet:
                await self.host.tell_user("Resumed: I may move again.")

    async def retell_task(self, again_after_s: float = RESEND_EVERY_S) -> None:
        """After the Core's reconnection: the task's pause notice it sent last may have died with the
        old connection (an inform is not resent like a request; seen: a resume lost in a link outage
        left a RApp paused for good). The Dynamic Agent is told the state as it is now, and once more
        `again_after_s` later, in case it comes back after the Core (a server without offline storage
        drops what is sent to it meanwhile). It ignores a state it already has."""
        for delay in (0.0, again_after_s):
            await asyncio.sleep(delay)
            await self._tell_task(self.estop_reason is not None, self.estop_reason or "resumed")

    async def _tell_task(self, paused: bool, reason: str) -> None:
        d = self.host.dynamic
        if d is not None and not d.ended.is_set():
            await self.host.notify(d.jid, C.TaskPaused(paused=paused, reason=reason), ontology=C.ONTOLOGY,
                              action="task_paused")

    async def stop_robot(self, everything: bool = False) -> None:
        """The base (and, `everything`, the head, joints and loudspeaker too) stops now."""
        self.driving = False
        try:
            if everything:
                await self.robot.halt("emergency stop")
            else:
                await self.robot.handle(ontology.robot.MoveStop())
        except Exception as e:  # noqa: BLE001 - stopping must not fail the destroy
            log.warning("stopping the robot failed: %s", e)

    # -- the safety check ----------------------------------------------------------------------
    async def nearest_obstacle(self) -> float | None:
        """How far the nearest obstacle ahead is beyond what the sensors can still measure
        (sonar reading or laser ray within ±30° minus the sensor's minimum range); None when the
        robot has neither sensor."""
        echo = await self.nearest_echo()
        return None if echo is None else echo.margin_m

    async def nearest_echo(self) -> ObstacleEcho | None:
        """The nearest reading ahead (sonar cone or laser ray within ±30°): its margin beyond the
        sensor's minimum range, its range and bearing from the robot (x forward); None without sensors."""
        best: ObstacleEcho | None = None
        has = self.robot.capabilities()  # asked, not probed: a missing sensor is no failed request per check
        reads = [req for cap, req in (("sonars", ontology.robot.GetSonars()), ("laser", ontology.robot.GetLaserScan()))
                 if cap in has]
        for req in reads:
            try:
                reply = await self.robot.handle(req)
            except RobotError as e:  # a failed reading (robot shutting down): the next check reads again
                log.debug("range reading failed: %s", e)
                continue
            if isinstance(reply, ontology.robot.SonarReading):
                bearing = reply.bearing or SONAR_BEARING_RAD
                readings = [(reply.left, bearing), (reply.right, -bearing)]
            else:
                readings = [(r, reply.angle_min + i * reply.angle_increment) for i, r in enumerate(reply.ranges)]
            for r, bearing in readings:
                if abs(bearing) <= AHEAD_RAD and (best is None or r - reply.range_min < best.margin_m):
                    # range and bearing from the base's centre, where the robot's pose is
                    x, y = reply.mount_x + r * math.cos(bearing), r * math.sin(bearing)
                    best = ObstacleEcho(r - reply.range_min, math.hypot(x, y), math.atan2(y, x))
        return best
