"""Dynamic Agent: runs a RApp's task FSM with its own XMPP identity (paper 000 sec. 5.2).

Lifecycle: log in -> task_status Init to the Core -> build the task -> Working -> run the FSM
(heartbeats to the Core meanwhile) -> stop its Cloud Agent -> Finished or Error -> log out.
"""
from __future__ import annotations

import asyncio
import logging
import time
from pathlib import Path

from spade.behaviour import PeriodicBehaviour

from behaviours import BehaviourHost, Outcome, PauseGate, exception_text
from ontology import core as C
from ontology import platform as P
from ontology.registry import parse_json
from ontology.errors import ErrorCode
from ontology.manifest import Manifest
from ontology.notifications import Notify
from ontology.trace import StructureEvent

from .base import RappAgent
from .errors import CloudAgentLost, RequestError
from .messages import bare
from .platform_directory import PlatformChooser
from .entry_point import load_entry_point

log = logging.getLogger("rapp.dynamic")
HEARTBEAT_S = 0.25


class _Heartbeat(PeriodicBehaviour):
    async def run(self) -> None:
        self.agent.beats += 1
        await self.agent.notify(self.agent.core, C.Heartbeat(seq=self.agent.beats),
                                ontology=C.ONTOLOGY, action="heartbeat")


class DynamicAgent(RappAgent):
    def __init__(self, name: str, *, manifest: Manifest, package_dir: str | Path, core: str,
                 platform: str, token: str = "", params: dict | None = None, robot=None,
                 settings=None, password: str | None = None):
        super().__init__(name, settings, password)
        self.robot_info = robot  # ontology.spawn.RobotInfo: the robot this run supervises
        self.manifest = manifest
        self.package_dir = Path(package_dir)
        self.core, self.platform, self.token = core, platform, token
        # which Platform agent serves each stateless service call (several may serve the domain)
        self.platform_chooser = PlatformChooser(self, platform, token) if platform else None
        self.params = {**manifest.params, **(params or {})}
        self.beats = 0
        self.task = None
        self.memory: dict = {}
        self.pause = PauseGate()  # the emergency stop as the task sees it (behaviours/pause.py)
        self.events: asyncio.Queue = asyncio.Queue(maxsize=100)  # the Core's notifications, newest kept
        self.event_handlers: dict[str, list] = {}
        self._handler_tasks: set[asyncio.Task] = set()

    @property
    def paused(self) -> str | None:
        """The emergency stop's reason while it is latched, else None."""
        return self.pause.reason

    def holds_requests_to(self, peer: str) -> bool:
        """Paused: requests to the Core (its held motions) do not time out meanwhile."""
        return self.pause.paused and bare(peer) == bare(self.core)

    async def on_unhandled(self, msg, info) -> None:
        """The Core's notice of an emergency stop (C.TaskPaused: `paused` is the reason while it
        lasts); the Platform's notice that our Cloud Agent's process ended: fail what waits for it."""
        if (info.ontology, info.action) == (C.ONTOLOGY, "task_paused") and bare(msg.sender) == bare(self.core):
            try:
                note = C.TaskPaused.model_validate(parse_json(msg.body))
            except Exception:  # noqa: BLE001 - malformed: ignored like any bad notification
                return
            if note.paused == self.pause.paused:
                return  # told again (the Core's re-tell after a reconnection): nothing changed
            if note.paused:
                self.pause.pause(note.reason or "emergency stop")
            else:
                self.pause.resume()
            self.record_structure(StructureEvent.TASK_PAUSED if note.paused else StructureEvent.TASK_RESUMED,
                                  reason=note.reason)
            return
        if (info.ontology, info.action) == (C.ONTOLOGY, "notification") and bare(msg.sender) == bare(self.core):
            self._on_notification(msg.body)
            return
        if (info.ontology, info.action) == (P.ONTOLOGY, "cloud_agent_down") and bare(msg.sender) == bare(self.platform):
            try:
                down = P.CloudAgentDown.model_validate(parse_json(msg.body))
            except Exception:  # noqa: BLE001 - malformed: kept as unhandled below
                down = None
            if down is not None:
                code = ErrorCode.CLOUD_RESTARTED if down.restarting or down.restarted else ErrorCode.CLOUD_LOST
                self.fail_pending(down.jid, CloudAgentLost(down.reason, code=code, peer=down.jid))
                if self.task is not None:
                    self.task.cloud.told(down.reason, restarting=down.restarting, restarted=down.restarted)
                self.record_structure("cloud-down", cloud=down.jid, restarted=down.restarted,
                                      restarting=down.restarting)
                return
        await super().on_unhandled(msg, info)

    def _on_notification(self, body: str) -> None:
        """A Core event (ontology/notifications.py): dropped and traced when expired, else queued
        for `next_event` and handed to the task's handlers for its topic."""
        try:
            note = Notify.model_validate(parse_json(body)).notification
        except Exception:  # noqa: BLE001 - malformed: ignored like any bad notification
            return
        if note.expired():
            self.record_structure(StructureEvent.NOTIFICATION_EXPIRED, topic=note.topic,
                                  late_s=round(time.time() - (note.expires or 0.0), 3))
            return
        if self.events.full():
            self.events.get_nowait()  # the oldest goes: a slow task sees the newest events
        self.events.put_nowait(note)
        for handler in self.event_handlers.get(note.topic, []):
            task = asyncio.ensure_future(handler(note))
            self._handler_tasks.add(task)  # the loop keeps only weak references to tasks
            task.add_done_callback(self._handler_done)

    def _handler_done(self, task: asyncio.Task) -> None:
        self._handler_tasks.discard(task)
        if not task.cancelled() and task.exception() is not None:
            log.error("event handler failed: %s", task.exception())

    async def _status(self, state: C.TaskState, detail: str = "") -> None:
        try:
            await self.request(self.core, C.TaskStatus(state=state, detail=detail[:2000]), timeout=10.0)
        except RequestError as e:
            log.warning("status %s not acknowledged: %s", state.value, e)

    async def run_to_end(self) -> int:
        """Start, run the task to its end, report, stop. Returns the process exit code."""
        await self.start(auto_register=True)  # its account may be only reserved (EphemeralAccounts.take)
        # import and build before Init: a slow import must not look like a hang to the Core
        behaviour, failure = self._build_task()
        self.activate("heartbeat", _Heartbeat(period=HEARTBEAT_S))
        await self._status(C.TaskState.INIT)
        outcome = Outcome(False, failure) if failure else await self._run_task(behaviour)
        if self.task is not None:
            try:
                await self.task.cloud.stop()
            except RequestError as e:
                log.warning("cloud agent stop failed: %s", e)
        state = C.TaskState.FINISHED if outcome.ok else C.TaskState.ERROR
        await self._status(state, outcome.reason)
        await self.stop()
        return 0 if outcome.ok else 1

    def _build_task(self):
        try:
            cls = load_entry_point(self.package_dir, self.manifest.entry_point)
            self.task = cls(self)
            behaviour = self.task.build()
            if hasattr(self.task, "root"):  # the SDK's Task shows its running states in its log
                self.task.root = behaviour
            return behaviour, None
        except (Exception, SystemExit) as e:  # noqa: BLE001 - a broken RApp is reported, not crashed on
            return None, f"task could not be built: {exception_text(e)}"

    async def _run_task(self, behaviour) -> Outcome:
        await self._status(C.TaskState.WORKING)
        host = BehaviourHost(behaviour, self.memory, pause=self.pause)
        self.activate("task", host)
        outcome = await host.outcome
        self.deactivate("task")
        return outcome
