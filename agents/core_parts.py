"""What the Core's members need of the Core and of each other, and the records they share.

The Core Agent (agents/core_agent.py) holds four members, each built with the Core (or another
member) as a narrow interface below, never the whole agent:

    hearing          agents/core_hearing.py     CoreHearing(HearingHost)
    robot_commands   agents/core_commands.py    RobotCommands(CommandsHost, ...)   the robot-API server, e-stop
    events           agents/core_events.py      CoreEvents(EventsHost, ...)        sensor events to the task
    strategies       agents/core_strategies.py  Strategies(StrategiesHost, SafetyLatch, ...)

This module is their floor: it imports none of them, so none imports the Core back.
"""
from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

from ontology.manifest import Manifest
from ontology.results import ReportRecord, TaskTrigger

from .identity import Identity
from .liveness import SilenceWatch
from .locks import ResourceLocks

if TYPE_CHECKING:
    from hearing.vad import HeardUtterance
    from robots.interface import RobotInterface

    from .process import AgentProcess, InProcessAgent


@dataclass
class DynamicSession:
    """The running Dynamic Agent: who it is, its process, and what it said last."""

    jid: str
    rapp: str
    version: str
    manifest: Manifest
    workdir: Path
    process: AgentProcess | InProcessAgent | None = None
    state: str = "Spawned"
    detail: str = ""
    last_beat: float = field(default_factory=time.monotonic)
    silence: SilenceWatch | None = None  # the looks at its process during the current silence
    forgiven_s: float = 0.0  # silence not held against it: the Core's own loop stalls and link outages
    ended: asyncio.Event = field(default_factory=asyncio.Event)
    hung: bool = False  # ended for missing heartbeats: killed without a grace period
    ready: asyncio.Event = field(default_factory=asyncio.Event)
    end_reason: str = ""
    account: Identity | None = None  # the run's ephemeral XMPP account, deleted at its end
    command: str = ""  # the owner's command that started it (text; "" when heard as sound)
    started: float | None = None  # when supervision was handed to it (s since the epoch)
    charged_s: float = 0.0  # of its time limit, used so far (s8: monotonic, paused time left out)
    reports: list[ReportRecord] = field(default_factory=list)  # what it reported, in order
    # what was refused it (by this Core, its sandbox, the Platform): {by, what, why, count}, told at its end
    refusals: list[dict] = field(default_factory=list)
    trigger: TaskTrigger = TaskTrigger.COMMAND  # what started it: the owner's command, or a schedule
    schedule_id: int | None = None


AHEAD_RAD = 0.52  # the safety check's cone: readings within ±30° of straight ahead (range and depth)


class ObstacleEcho(NamedTuple):
    """The nearest range reading ahead (RobotCommands.nearest_echo)."""

    margin_m: float  # beyond the sensor's minimum range
    range_m: float  # from the base's centre (the robot's pose)
    bearing_rad: float  # from the robot's heading, counter-clockwise


# -- what each member asks of the Core -----------------------------------------------------------
class EventsHost(Protocol):
    """CoreEvents: the running task, the robot's camera, one-way messages, behaviours to start."""

    robot: RobotInterface
    dynamic: DynamicSession | None

    async def notify(self, to: str, content: Any, *, ontology: str, action: str) -> None: ...

    def activate(self, name: str, behaviour: Any, template: Any = None) -> None: ...

    def deactivate(self, name: str) -> None: ...


class CommandsHost(Protocol):
    """RobotCommands: the robot, the running task, the owner's chat, the trace (its s9 passes are
    traced under the Core's `address`)."""

    robot: RobotInterface
    robot_id: str
    dynamic: DynamicSession | None
    tracer: Any

    @property
    def address(self) -> str: ...

    def record_structure(self, event: str, **fields: Any) -> None: ...

    async def tell_user(self, text: str, speak: bool = True, label: str = "") -> None: ...

    async def notify(self, to: str, content: Any, *, ontology: str, action: str) -> None: ...

    def in_background(self, coro: Coroutine[Any, Any, Any]) -> None: ...


class StrategiesHost(Protocol):
    """Strategies: the robot (to back off, to place an incident), the running task, the owner's chat."""

    robot: RobotInterface
    dynamic: DynamicSession | None

    def record_structure(self, event: str, **fields: Any) -> None: ...

    async def tell_user(self, text: str, speak: bool = True, label: str = "") -> None: ...

    def in_background(self, coro: Coroutine[Any, Any, Any]) -> None: ...


class SafetyLatch(Protocol):
    """The emergency stop and the range sensors as the strategies and the safety check see them
    (RobotCommands has them)."""

    estop_reason: str | None
    estop_by: str | None
    fail_held: tuple[str, str] | None
    driving: bool
    safety_distance: float | None
    locks: ResourceLocks

    @property
    def robot(self) -> RobotInterface: ...

    async def emergency_stop(self, reason: str, by: str = "owner") -> None: ...

    async def safety_stop(self, reason: str) -> None: ...

    async def resume_motion(self, by: str = "owner") -> None: ...

    async def nearest_obstacle(self) -> float | None: ...

    async def nearest_echo(self) -> ObstacleEcho | None: ...


class HearingHost(Protocol):
    """CoreHearing: the robot's microphone, whether the Core listens for a command (s3), its own
    sentences (never heard as the owner's), where a heard command and a supervision word go."""

    robot: RobotInterface
    sentences_begun: int  # sentences given to the loudspeaker so far

    @property
    def listening(self) -> bool: ...

    def speaking(self) -> bool: ...

    def record_structure(self, event: str, **fields: Any) -> None: ...

    def in_background(self, coro: Coroutine[Any, Any, Any]) -> None: ...

    def heard_command(self, utterance: HeardUtterance) -> Awaitable[None]: ...

    def heard_supervision_word(self, word: str) -> Awaitable[None]: ...
