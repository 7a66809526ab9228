"""Core Agent messages from its Dynamic Agent: task status, heartbeats, reports for the user.

Robot-API requests are in ontology "robot" (ontology/robot.py); the Core serves them only from
the current Dynamic Agent.
"""
from __future__ import annotations

from enum import Enum
from typing import Any

from .registry import Action, Content, Done, action

ONTOLOGY = "core"


class TaskState(str, Enum):
    INIT = "Init"
    WORKING = "Working"
    FINISHED = "Finished"
    ERROR = "Error"


@action("task_status", ontology=ONTOLOGY, reply=Done, group="task")
class TaskStatus(Action):
    state: TaskState
    detail: str = ""


@action("report", ontology=ONTOLOGY, reply=Done, group="task")
class Report(Action):
    """Something the Core must tell the user (spoken and/or sent as chat)."""

    text: str
    data: dict[str, Any] = {}


@action("task_paused", ontology=ONTOLOGY, reply=Done, group="task")
class TaskPaused(Action):
    """The Core to its Dynamic Agent (a notification): the emergency stop latched (paused=True: the
    task pauses, its robot motions are held, not failed) or was released (paused=False)."""

    paused: bool
    reason: str = ""


@action("release_stop", ontology=ONTOLOGY, reply=Done, group="task")
class ReleaseStop(Action):
    """The supervising Dynamic Agent releases an emergency stop its robot's safety check latched (say,
    after it has backed away from the obstacle). An owner's stop is the owner's to release: refused."""


@action("heartbeat", ontology=ONTOLOGY, reply=Done, group="task")
class Heartbeat(Action):
    seq: int = 0


class CoreState(Content):
    state: str
    active_behaviours: list[str]
    dynamic_agent: str | None = None
    rapp: str | None = None


@action("get_state", ontology=ONTOLOGY, reply=CoreState, group="inspect", idempotent=True)
class GetState(Action):
    pass
