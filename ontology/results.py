"""A task's results as data: what the Core keeps of each command it takes, and tells its owner's client.

The Core keeps, per command, the RApp's reports (text and data, as the RApp sent them with
`core.Report`) and how it ended: which stage it reached (understood, downloaded, started, ran), the
task's last state, why it ended, what the sandbox refused it, where its output files are, when it
started and ended. The owner's client (a chat client that speaks ACL, a scenario) subscribes once
with FIPA subscribe (`SubscribeTasks`); the Core then sends it, one way, each report as it comes
(`TaskReported`) and each command's end (`TaskEnded`, carrying the whole `TaskRecord`). Chat text
stays for people: nothing needs to read "X finished." to learn what happened.
"""
from __future__ import annotations

import json
from enum import StrEnum
from typing import Any, Literal

from pydantic import Field

from .registry import Action, Content, Done, action

ONTOLOGY = "core"
# a TaskEnded travels as one XMPP message: its reports are cut to fit well under a message's limit
# (agents/base.py MAX_BODY, 256 K characters); each report was sent on its own as it came
RECORD_BUDGET = 200_000


class TaskStage(StrEnum):
    """How far a command got: where it ended."""

    UNDERSTAND = "understand"  # no RApp was chosen (s4: not understood, not recognised)
    DOWNLOAD = "download"  # the RApp could not be fetched or checked (s5)
    START = "start"  # its Dynamic Agent did not start (s6)
    RUN = "run"  # it ran and ended in any way (s8-s10)


class TaskTrigger(StrEnum):
    """What started a task (paper 000 sec. 7: "upon request from the user or executing a scheduled task")."""

    COMMAND = "command"  # the owner's command, said or written
    SCHEDULED = "scheduled"  # a schedule the Core keeps came due (agents/scheduler.py)


class ReportRecord(Content):
    """One report of the RApp to its owner (core.Report), stamped when the Core took it."""

    text: str
    data: dict[str, Any] = {}
    stamp: float = Field(description="when the Core received it (s since the epoch)")


class RefusalRecord(Content):
    """Something the system refused the RApp during its run (the sandbox, a service, the Core)."""

    what: str
    by: str = ""
    why: str = ""
    count: int = Field(1, description="how many times the same thing was refused")


class TaskRecord(Content):
    """A command's end: everything a scenario or the owner's client needs to score it."""

    robot_id: str
    command: str = Field("", description="the owner's command as text ('' when it was heard as sound)")
    rapp: str = Field("", description="the RApp chosen ('' when the command was not understood)")
    version: str = ""
    stage: TaskStage
    state: str = Field("", description="the task's last state (Finished, Error, ...); '' when it never ran")
    ok: bool = Field(description="the task finished and nothing was refused it")
    reason: str = Field("", description="why it ended as it did")
    told: str = Field("", description="what the owner was told at its end")
    reports: list[ReportRecord] = []
    reports_omitted: int = Field(0, description="earliest reports left out to fit the message (sent as they came)")
    refusals: list[RefusalRecord] = []
    outputs: str | None = Field(None, description="the Core's directory of the RApp's files (Task.outputs)")
    started: float | None = Field(None, description="when its Dynamic Agent was spawned (s since the epoch)")
    ended: float = Field(description="when the Core recorded its end (s since the epoch)")
    trigger: TaskTrigger = Field(TaskTrigger.COMMAND, description="what started it")
    schedule_id: int | None = Field(None, description="the schedule it ran for (trigger scheduled)")

    def fitted(self, budget: int = RECORD_BUDGET) -> "TaskRecord":
        """This record, its earliest reports left out (and counted) until its JSON fits `budget` characters."""
        sizes = [len(json.dumps(r.model_dump(), separators=(",", ":"))) for r in self.reports]
        room = budget - len(self.model_copy(update={"reports": []}).model_dump_json())
        drop = 0
        while drop < len(sizes) and sum(sizes[drop:]) + len(sizes) > room:
            drop += 1
        if not drop:
            return self
        return self.model_copy(update={"reports": self.reports[drop:], "reports_omitted": self.reports_omitted + drop})


class ScheduleRecord(Content):
    """A schedule the Core keeps (agents/scheduler.py): a RApp to start at a time, once or every day."""

    id: int
    robot_id: str
    rapp: str
    params: dict[str, str] = {}
    command: str = Field("", description="the owner's words that made it")
    kind: Literal["once", "daily"]
    time_of_day: str | None = Field(None, description="daily: HH:MM, the robot's local time")
    due: float = Field(description="its next start (s since the epoch, the robot's clock)")
    window_s: float = Field(description="how long its task may run (the RApp's time limit): what clashes with it")


class ScheduleEvent(StrEnum):
    KEPT = "kept"  # a schedule made
    REFUSED = "refused"  # one the Core cannot keep, with the reason
    CANCELLED = "cancelled"  # one forgotten at the owner's word
    MISSED = "missed"  # one that came due while the robot could not start it (busy, stopped)
    LISTED = "listed"  # the schedules kept, as asked


@action("schedule_changed", ontology=ONTOLOGY, reply=Done, group="task")
class ScheduleChanged(Action):
    """One way, to the task subscribers: the Core's schedules changed (or were refused a change)."""

    robot_id: str
    event: ScheduleEvent
    schedules: list[ScheduleRecord] = []  # the schedules it concerns (kept, cancelled, missed, listed)
    reason: str = ""  # refused, missed: why
    command: str = ""  # the owner's words


@action("subscribe_tasks", ontology=ONTOLOGY, reply=Done, group="task")
class SubscribeTasks(Action):
    """FIPA subscribe from the Core's owner: tell me every task's reports and every command's end,
    until the Core stops. Only the owner the Core serves may subscribe."""


@action("task_reported", ontology=ONTOLOGY, reply=Done, group="task")
class TaskReported(Action):
    """One way, to the subscribers: the running RApp reported this."""

    robot_id: str
    rapp: str
    report: ReportRecord


@action("task_ended", ontology=ONTOLOGY, reply=Done, group="task")
class TaskEnded(Action):
    """One way, to the subscribers: a command ended (a task that ran, or one that never started)."""

    record: TaskRecord
