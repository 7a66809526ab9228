"""Reactive strategies (paper 004): what the Core does by itself when its safety check stops the robot
in the middle of a plan, before it hands the robot back to the plan.

The safety check (core_behaviours.SafetyMonitor) or the robot's own collision protection latches the
emergency stop (by "safety"): the task pauses, its motion is held. Then, in the order of STRATEGIES:

    wait-for-clear   something (a person crossing, a door swinging) may move away: wait up to
                     `wait_s` for the range sensors to read clear ahead; if they do, release the stop
                     and the held motion goes on where it was going
    back-off         still blocked: back away `back_off_m` (the Core's own motion, acting for the task:
                     it inherits the task's base lock, paper 003 sec. V-B, and gives it back after;
                     the base free, it locks it), release the stop and fail the
                     held motion with code `blocked`, so the plan re-plans around what stands there
                     (an obstacle event with the reading just before tells subscribers where it is)
    no-progress      stopped again where it was stopped before (within `progress_m`) after
                     `max_resumes` resumes, or after `max_pause_s` s paused there: waiting is not
                     tried again; back off and fail the held motion (`blocked`). A robot wedged on
                     something its range sensors do not see (a door leaf below the laser) reads clear
                     the moment it stops; without this rule it would stop and resume forever.

Each step is traced (structure `strategy`: name, phase start/end, outcome). The stops at one place
make one safety incident: the owner hears one folded line when it is over (`safety-incident` in the
trace: how often, what the Core did, how it ended), not one message per stop. An owner's stop never
starts a strategy: only the owner releases it. Lost localization belongs to the RApp's plan monitor
(the Core does not localize)."""
from __future__ import annotations

import asyncio
import logging
import math
import time
from dataclasses import dataclass, field
from collections.abc import Awaitable, Callable
from typing import Any, NamedTuple

import ontology.robot
from ontology.errors import ErrorCode
from ontology.notifications import EventTopic
from behaviours.pause import PAUSE_ALLOWANCE_S
from ontology.trace import StructureEvent

from .core_parts import ObstacleEcho, SafetyLatch, StrategiesHost

log = logging.getLogger("rapp.core")


class StrategyRule(NamedTuple):
    name: str
    trigger: str
    action: str


STRATEGIES = (
    StrategyRule("wait-for-clear", "obstacle ahead within the safety distance", "wait until clear, hand back"),
    StrategyRule("back-off", "still blocked after waiting", "back away, hand back with the motion failed (blocked)"),
    StrategyRule("no-progress", "stopped at the same place after max_resumes resumes or max_pause_s paused",
                 "back away at once, hand back with the motion failed (blocked)"),
)


@dataclass
class Incident:
    """The safety stops at one place (within Strategies.progress_m of the first)."""

    x: float
    y: float
    stops: int = 0
    resumes: int = 0  # hand-backs by wait-for-clear since the last back-off (no progress in between)
    paused_s: float = 0.0  # paused by the safety there since the last back-off
    last_stop: float = field(default_factory=time.monotonic)
    done: dict[str, int] = field(default_factory=dict)  # strategy -> times it handed back

    def line(self, end: str) -> str:
        """The owner's one line about it."""
        times = "once" if self.stops == 1 else f"{self.stops} times"
        did = [f"{verb} {'once' if n == 1 else f'{n} times'}" for key, verb in
               (("wait-for-clear", "waited for it to clear"), ("back-off", "backed off"),
                ("no-progress", "gave up on that way")) if (n := self.done.get(key, 0))]
        return f"Safety: stopped {times} for an obstacle ahead near ({self.x:.1f}, {self.y:.1f}); " \
               + (", ".join(did) + "; " if did else "") + f"{end}."


class Strategies:
    """The Core's member for reactive strategies (`core.strategies`): what it needs of the Core is
    `StrategiesHost`, of the emergency stop and the range sensors `SafetyLatch` (the Core's
    RobotCommands), and `publish_echo` tells the task where the obstacle stands (CoreEvents)."""

    wait_s = 2.0
    back_off_m = 0.25
    clear_factor = 2.0  # "clear" = the margin ahead exceeds this many safety distances
    progress_m = 0.5  # a stop this near an incident's first stop is no progress: the same incident
    max_resumes = 3  # resumes without progress before the way counts as blocked
    max_pause_s = 30.0  # paused by the safety at one place (since its last back-off) before the same
    went_on_m = 1.0  # an incident is over once the robot is this far from it...
    quiet_s = 60.0  # ... or this long without another stop there
    pause_allowance_s = PAUSE_ALLOWANCE_S  # the task's time limit stops while paused, this long at most

    def __init__(self, host: StrategiesHost, latch: SafetyLatch,
                 publish_echo: Callable[[EventTopic, ObstacleEcho], Awaitable[Any]]):
        self.host, self.latch, self.publish_echo = host, latch, publish_echo
        self.incident: Incident | None = None

    def _strategy_trace(self, name: str, phase: str, **fields) -> None:
        self.host.record_structure(StructureEvent.STRATEGY, strategy=name, phase=phase, **fields)

    async def react_to_obstacle(self) -> str:
        """Run the strategies after a safety stop; returns the one that handed the robot back ('' when
        the stop was meanwhile taken over by the owner or released by someone else)."""
        loop = asyncio.get_running_loop()
        incident, began = await self._incident_stop(), loop.time()
        try:
            return await self._react(incident)
        finally:
            incident.paused_s += loop.time() - began

    async def _react(self, incident: Incident) -> str:
        if incident.resumes >= self.max_resumes or incident.paused_s >= self.max_pause_s:
            why = (f"stopped {incident.resumes + 1} times within {self.progress_m:g} m"
                   if incident.resumes >= self.max_resumes else f"paused {incident.paused_s:.0f} s there")
            return await self._back_off(incident, STRATEGIES[2].name, f"no progress: {why}")
        name = STRATEGIES[0].name
        self._strategy_trace(name, "start")
        clear = await self._wait_clear(self.wait_s)
        self._strategy_trace(name, "end", outcome="clear" if clear else "still blocked")
        if not self._still_ours():
            return ""
        if clear:
            incident.resumes += 1
            incident.done[name] = incident.done.get(name, 0) + 1
            await self.latch.resume_motion(by=f"strategy:{name}")
            return name
        return await self._back_off(incident, STRATEGIES[1].name, "the way ahead stayed blocked")

    async def _back_off(self, incident: Incident, name: str, why: str) -> str:
        heir = f"core:{name}"
        try:
            async with self.latch.locks.acting_for("base", heir, timeout=self.wait_s) as giver:
                self._strategy_trace(name, "start", distance_m=self.back_off_m, why=why,
                                     base=self.latch.locks.chain("base"))
                await self.host.robot.handle(ontology.robot.MoveTo(x=-self.back_off_m, y=0.0, theta=0.0))
            outcome = "backed off"
        except Exception as e:  # noqa: BLE001 - blocked behind too: hand back all the same
            giver, outcome = None, f"could not back off: {e}"
        self._strategy_trace(name, "end", outcome=outcome, base_given_back_to=giver)
        if not self._still_ours():
            return ""
        echo = await self.latch.nearest_echo()  # where it stands: the plan's monitor enters it into the map
        if echo is not None:
            await self.publish_echo(EventTopic.OBSTACLE, echo)
        incident.resumes, incident.paused_s = 0, 0.0  # the task re-plans: a new motion
        incident.done[name] = incident.done.get(name, 0) + 1
        did = "the Core backed off" if outcome == "backed off" else f"the Core {outcome}"
        self.latch.fail_held = (ErrorCode.BLOCKED, f"{why}: {did} (strategy {name})")
        await self.latch.resume_motion(by=f"strategy:{name}")
        return name

    def _still_ours(self) -> bool:
        return self.latch.estop_reason is not None and self.latch.estop_by == "safety"

    async def _wait_clear(self, seconds: float) -> bool:
        loop = asyncio.get_running_loop()
        end = loop.time() + seconds
        while loop.time() < end and self._still_ours():
            nearest = await self.latch.nearest_obstacle()
            if nearest is None or nearest > self.clear_factor * (self.latch.safety_distance or 0.0):
                return True
            await asyncio.sleep(0.2)
        return False

    # -- safety incidents: the stops at one place, one line to the owner ------------------------
    async def _pose_xy(self) -> tuple[float, float] | None:
        try:
            pose = await self.host.robot.handle(ontology.robot.GetGlobalPose())
        except Exception as e:  # noqa: BLE001 - a robot shutting down: no place to compare
            log.debug("no pose for the safety incident: %s", e)
            return None
        return pose.x, pose.y

    async def _incident_stop(self) -> Incident:
        """The incident this safety stop belongs to: the open one when the robot has not got away
        from it (progress_m), else a new one (the open one is closed: it went on)."""
        xy = await self._pose_xy() or (math.nan, math.nan)
        open_ = self.incident
        if open_ is not None and not math.dist(xy, (open_.x, open_.y)) <= self.progress_m:
            await self.close_incident("went on")
            open_ = None
        if open_ is None:
            open_ = self.incident = Incident(*xy)
            self.host.in_background(self._watch_incident(open_))
        open_.stops += 1
        open_.last_stop = time.monotonic()
        return open_

    async def _watch_incident(self, incident: Incident) -> None:
        """Closes the incident when the robot has got away from it, after quiet_s without a stop there,
        or when the task it stopped has ended."""
        session = self.host.dynamic
        while self.incident is incident:
            await asyncio.sleep(0.5)
            if self.incident is not incident:
                return
            if session is None or self.host.dynamic is not session or session.ended.is_set():
                if not self._still_ours() or time.monotonic() - incident.last_stop > 4 * self.wait_s:
                    await self.close_incident("the task ended")  # (told what the strategy did first)
            elif self.latch.estop_reason is None:
                xy = await self._pose_xy()
                if xy is not None and math.dist(xy, (incident.x, incident.y)) >= self.went_on_m:
                    await self.close_incident("went on")
                elif time.monotonic() - incident.last_stop >= self.quiet_s:
                    await self.close_incident("went on")  # (the trace says: quiet_s without a stop there)

    async def close_incident(self, end: str) -> None:
        """The open incident is over: traced in full, told to the owner in one line."""
        incident, self.incident = self.incident, None
        if incident is None:
            return
        self.host.record_structure(StructureEvent.SAFETY_INCIDENT, x=round(incident.x, 3), y=round(incident.y, 3),
                              stops=incident.stops, strategies=dict(incident.done), end=end)
        await self.host.tell_user(incident.line(end), speak=False)

    def waiting_for(self) -> str:
        """What a running task waits for now, from the Core's side ('' when nothing the Core knows of)."""
        if self.latch.estop_reason is not None and self.latch.estop_by == "owner":
            return 'your "resume" (you stopped the robot)'
        i = self.incident
        if self.latch.estop_reason is not None:
            return f"the way ahead to clear (safety stop: {self.latch.estop_reason})"
        if i is not None:
            return f"a way past the obstacle near ({i.x:.1f}, {i.y:.1f}) (stopped there {i.stops} times)"
        return ""
