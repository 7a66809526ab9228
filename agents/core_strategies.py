"""Reactive strategies (paper 004): what the Core does by itself when its safety check stops the robot
in the middle of a plan, before it hands the robot back to the plan.

The safety check (core_behaviours.SafetyMonitor) latches the emergency stop (by "safety"): the task
pauses, its motion is held. Then, in the order of STRATEGIES:

    wait-for-clear   something (a person crossing, a door swinging) may move away: wait up to
                     `wait_s` for the range sensors to read clear ahead; if they do, release the stop
                     and the held motion goes on where it was going
    back-off         still blocked: back away `back_off_m` (the Core's own motion, acting for the task:
                     it inherits the task's base lock, paper 003 sec. V-B, and gives it back after;
                     the base free, it locks it), release the stop and fail the
                     held motion with code `blocked`, so the plan re-plans around what stands there
                     (an obstacle event with the reading just before tells subscribers where it is)

Each step is traced (structure `strategy`: name, phase start/end, outcome). An owner's stop never
starts a strategy: only the owner releases it. Lost localization belongs to the RApp's plan monitor
(the Core does not localize)."""
from __future__ import annotations

import asyncio
import logging
from typing import NamedTuple

import ontology.robot
from ontology.errors import ErrorCode
from ontology.notifications import EventTopic
from ontology.trace import StructureEvent

log = logging.getLogger("rapp.core")


class StrategyRule(NamedTuple):
    name: str
    trigger: str
    action: str


STRATEGIES = (
    StrategyRule("wait-for-clear", "obstacle ahead within the safety distance", "wait until clear, hand back"),
    StrategyRule("back-off", "still blocked after waiting", "back away, hand back with the motion failed (blocked)"),
)


class Strategies:
    """Mixed into CoreAgent (needs estop_reason/estop_by, resume_motion, nearest_obstacle, nearest_echo,
    publish_echo, robot, locks, safety_distance, record_structure)."""

    wait_s = 2.0
    back_off_m = 0.25
    clear_factor = 2.0  # "clear" = the margin ahead exceeds this many safety distances

    def _strategy_trace(self, name: str, phase: str, **fields) -> None:
        self.record_structure(StructureEvent.STRATEGY, strategy=name, phase=phase, **fields)

    async def react_to_obstacle(self) -> str:
        """Run the strategies after a safety stop; returns the one that handed the robot back ('' when
        the stop was meanwhile taken over by the owner or released by someone else)."""
        name = STRATEGIES[0].name
        self._strategy_trace(name, "start")
        clear = await self._wait_clear(self.wait_s)
        self._strategy_trace(name, "end", outcome="clear" if clear else "still blocked")
        if not self._still_ours():
            return ""
        if clear:
            await self.resume_motion(by=f"strategy:{name}")
            return name
        name = STRATEGIES[1].name
        heir = f"core:{name}"
        try:
            async with self.locks.acting_for("base", heir, timeout=self.wait_s) as giver:
                self._strategy_trace(name, "start", distance_m=self.back_off_m, base=self.locks.chain("base"))
                await self.robot.handle(ontology.robot.MoveTo(x=-self.back_off_m, y=0.0, theta=0.0))
            outcome = "backed off"
        except Exception as e:  # noqa: BLE001 - blocked behind too: hand back all the same
            giver, outcome = None, f"could not back off: {e}"
        self._strategy_trace(name, "end", outcome=outcome, base_given_back_to=giver)
        if not self._still_ours():
            return ""
        echo = await self.nearest_echo()  # where it stands: the plan's monitor enters it into the map
        if echo is not None:
            await self.publish_echo(EventTopic.OBSTACLE, echo)
        self.fail_held = (ErrorCode.BLOCKED, "the way ahead stayed blocked: the Core backed off (strategy back-off)")
        await self.resume_motion(by=f"strategy:{name}")
        return name

    def _still_ours(self) -> bool:
        return self.estop_reason is not None and self.estop_by == "safety"

    async def _wait_clear(self, seconds: float) -> bool:
        loop = asyncio.get_running_loop()
        end = loop.time() + seconds
        while loop.time() < end and self._still_ours():
            nearest = await self.nearest_obstacle()
            if nearest is None or nearest > self.clear_factor * (self.safety_distance or 0.0):
                return True
            await asyncio.sleep(0.2)
        return False
