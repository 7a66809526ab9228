"""The records of a run trace (agents/tracing.py writes them, one JSON object a line).

Every record has `t` (wall-clock seconds), `kind`, `pid` (the writing process) and, except for
records of no agent, `agent` (the writer's address). The kinds:

  message    one per message and side: dir=send|recv, sender, receiver, performative (or "chat"),
             conversation_id, ontology, action, message_id, in_reply_to, path=direct|xmpp, size,
             content (secrets masked, capped)
  agent      event=started|stopped|start-failed|disconnected|reconnected
  behaviour  event=activated|deactivated, behaviour
  structure  event=StructureEvent (below), then the event's own fields (rapp, dynamic, cloud, ...)
  state      event=enter, fsm, state (FSM states of embodied behaviours); conversation_id on the
             states of a request's own pass (the Platform's fig. 6 request FSM, the Core's s9)
  timeout    peer, action, conversation_id, timeout_s (a request not answered in time)
  retry      peer, action, attempt (an idempotent request sent again)
  resend     peer, conversation_id (a request sent again after reconnecting)
  dropped    sender, reason[, performative, conversation_id] (a message nobody took)
  duplicate  sender, conversation_id, answered (a request received twice)
  progress   fraction (0..1 or null), text (a RApp's own estimate: rapps.sdk Task.progress)
  log        level, message, state (a RApp's log record, with the FSM state it was in: Task.log)
  blackboard key, value, writer (a write to a RApp's typed blackboard: rapps.sdk Blackboard)

A record a RApp process wrote (through its Core's or Platform's relay, agents/tracing.py
TraceRelay) carries `origin` (the RApp's JID, which its `agent` is forced to; what it claimed is kept
as `claimed_agent`): untrusted, never another agent's.

Writing is not validated (a record is written for every message); `parse_record` validates a
record when a trace is read (agents.tracing.read_trace(..., validate=True)).
"""
from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from .acl import FINAL, OPENING, Performative

CHAT = "chat"  # the performative field of a plain chat message (no FIPA performative)


class RecordKind(StrEnum):
    MESSAGE = "message"
    AGENT = "agent"
    BEHAVIOUR = "behaviour"
    STRUCTURE = "structure"
    STATE = "state"
    TIMEOUT = "timeout"
    RETRY = "retry"
    RESEND = "resend"
    DROPPED = "dropped"
    DUPLICATE = "duplicate"
    PROGRESS = "progress"
    LOG = "log"
    BLACKBOARD = "blackboard"


class StructureEvent(StrEnum):
    """Every `event` of a structure record the agents write (record_structure); tests/
    test_trace_records.py fails on a record_structure("...") literal that is not here."""

    # the Core
    INIT = "init"  # its FSM starts
    SUPERVISION_SPOTTING = "supervision-spotting"  # a supervision word (stop...) heard while a RApp runs
    REGISTER = "register"  # robot registered with the Platform/Store (also written by them)
    ACCOUNTS_SWEPT = "accounts-swept"  # leftover XMPP accounts of dead agents deleted (Core, Platform)
    VOCABULARY = "vocabulary"  # the RApps and keywords it understands
    CATALOGUE_CHANGED = "catalogue-changed"  # the Store's catalogue changed
    COMMAND = "command"  # the owner's command text
    DOWNLOAD = "download"  # a package downloaded (Core) / served (Store)
    SPAWN = "spawn"  # a Dynamic Agent started
    HANDOFF = "handoff"  # supervision handed to the Dynamic Agent
    STATUS = "status"  # the Dynamic Agent's task status
    HEARTBEAT_LATE = "heartbeat-late"  # the Dynamic Agent is silent but alive (agents/liveness.py): waited for
    ENDED = "ended"  # the task ended (finished, error, lost)
    DESTROY = "destroy"  # the Dynamic Agent stopped
    RESUME = "resume"  # the Core supervises again
    ACCOUNT_DELETED = "account-deleted"  # a Dynamic/Cloud Agent's XMPP account deleted
    ACCOUNT_KEPT = "account-kept"  # ... or not (deletion failed)
    SPEECH_HEARD = "speech-heard"  # an utterance cut from the microphone by voice activity detection
    KEYWORD_SPOTTING = "keyword-spotting"  # s4a: the keyword spotter's answer on the robot
    SPEECH_RECOGNITION = "speech-recognition"  # s4b: the Platform's recognition of a longer utterance
    SPEECH_JOINED = "speech-joined"  # s4b: the owner went on after a pause: two utterances recognised as one
    ESTOP = "estop"  # emergency stop
    ESTOP_RELEASED = "estop-released"
    MOTION_HELD = "motion-held"  # a motion of the task waits for the emergency stop's release
    MOTION_RESUMED = "motion-resumed"  # ... and was (re-)issued after it
    STRATEGY = "strategy"  # a reactive strategy of the Core (phase start/end; agents/core_strategies.py)
    SAFETY_INCIDENT = "safety-incident"  # the safety stops at one place are over (told to the owner in one line)
    # the Core's schedules (agents/scheduler.py)
    SCHEDULE_KEPT = "schedule-kept"  # a schedule made at the owner's word
    SCHEDULE_REFUSED = "schedule-refused"  # ... or refused, with the reason
    SCHEDULE_CANCELLED = "schedule-cancelled"  # schedules forgotten at the owner's word
    SCHEDULE_LISTED = "schedule-listed"  # the schedules told to the owner
    SCHEDULE_DUE = "schedule-due"  # a schedule's time came: its RApp starts (trigger "scheduled")
    SCHEDULE_MISSED = "schedule-missed"  # its time came while the robot could not start it
    SCHEDULE_ASKED = "schedule-asked"  # a schedule heard by voice: the owner asked to confirm it (agents/core_confirm.py)
    SCHEDULE_ANSWER = "schedule-answer"  # ... and what the owner answered (yes, no, none), by voice or chat
    # a Dynamic Agent's plan monitor (rapps/sdk/monitor.py)
    PLAN_FAILED = "plan-failed"  # an expectation of the running plan failed: the task re-plans
    OBSTACLE_MARKED = "obstacle-marked"  # an obstacle entered into the Platform's temporary layer
    OBSTACLE_CLEARED = "obstacle-cleared"  # ... and taken out, seen free again
    # the Store
    PUBLISH = "publish"  # a package published
    BUILD = "build"  # a published version's build for one robot type began or ended (agents/store_build.py)
    REFUSED = "refused"  # an operation refused to a caller without the right (Core, Store, Platform, a sandbox)
    REFUSALS = "refusals"  # what a RApp run was refused, told to its owner at its end (the Core)
    LOGIN_FAILED = "login-failed"  # a failed SASL login (the embedded server)
    REGISTERED = "registered"  # an account made by in-band registration (the embedded server)
    REGISTRATION_REFUSED = "registration-refused"  # ... or refused (the name was taken)
    # the Platform
    CLOUD_SPAWN = "cloud-spawn"  # a Cloud Agent started (or restarted)
    CLOUD_LOST = "cloud-lost"  # a Cloud Agent's process died
    CLOUD_DESTROY = "cloud-destroy"  # a Cloud Agent stopped
    REPLICA_JOINED = "replica-joined"  # the primary Platform heard a replica's first load report
    REPLICA_REGISTERED = "replica-registered"  # a replica Platform's first report was accepted
    # the Dynamic Agent
    CLOUD_DOWN = "cloud-down"  # its Cloud Agent is gone (restarted or not)
    TASK_PAUSED = "task-paused"  # the emergency stop latched: the task holds (not failed)
    TASK_RESUMED = "task-resumed"  # ... and was released: the task goes on
    NOTIFICATION_EXPIRED = "notification-expired"  # a Core event arrived after its expiry: dropped


class AgentEvent(StrEnum):
    STARTED = "started"
    STOPPED = "stopped"
    START_FAILED = "start-failed"
    DISCONNECTED = "disconnected"
    RECONNECTED = "reconnected"


class BehaviourEvent(StrEnum):
    ACTIVATED = "activated"
    DEACTIVATED = "deactivated"


class Direction(StrEnum):
    SEND = "send"
    RECV = "recv"


class DeliveryPath(StrEnum):
    DIRECT = "direct"  # in-process, from agent to agent
    XMPP = "xmpp"  # through the XMPP server


# as the trace spells them (the views compare strings): the answers that close a request (agree
# only advances it), the requests the trace views expect such an answer to, and what the HTML view
# draws as an opening arrow
FINAL_ANSWERS = frozenset(p.value for p in FINAL)
EXPECT_ANSWER = frozenset(p.value for p in (Performative.REQUEST, Performative.QUERY_REF))
OPENING_OR_CHAT = [p.value for p in Performative if p in OPENING] + [CHAT]


class _Record(BaseModel):
    # a field added to a record later does not make older readers drop it; a missing one does
    model_config = ConfigDict(extra="allow", frozen=True)

    t: float
    pid: int
    agent: str = ""


class MessageRecord(_Record):
    """A message as one side saw it (every message is traced by its sender and its receiver,
    except the chat of an external XMPP client: by one side only)."""

    kind: Literal[RecordKind.MESSAGE]
    dir: Direction
    agent: str
    sender: str
    receiver: str
    performative: Performative | Literal["chat"]
    conversation_id: str
    ontology: str
    action: str
    message_id: str
    in_reply_to: str
    path: DeliveryPath
    size: int
    content: str


class StructureRecord(_Record):
    """A change of the system's structure or supervision; its other fields depend on the event."""

    kind: Literal[RecordKind.STRUCTURE]
    event: StructureEvent
    agent: str


class AgentRecord(_Record):
    kind: Literal[RecordKind.AGENT]
    event: AgentEvent
    agent: str


class BehaviourRecord(_Record):
    kind: Literal[RecordKind.BEHAVIOUR]
    event: BehaviourEvent
    agent: str
    behaviour: str


class StateRecord(_Record):
    kind: Literal[RecordKind.STATE]
    event: Literal["enter"]
    fsm: str
    state: str
    conversation_id: str = ""  # the request whose pass entered it ("" for an agent's own FSM)


class TimeoutRecord(_Record):
    kind: Literal[RecordKind.TIMEOUT]
    peer: str
    action: str
    conversation_id: str
    timeout_s: float


class RetryRecord(_Record):
    kind: Literal[RecordKind.RETRY]
    peer: str
    action: str
    attempt: int


class ResendRecord(_Record):
    kind: Literal[RecordKind.RESEND]
    peer: str
    conversation_id: str


class DroppedRecord(_Record):
    kind: Literal[RecordKind.DROPPED]
    sender: str
    reason: str


class DuplicateRecord(_Record):
    kind: Literal[RecordKind.DUPLICATE]
    sender: str
    conversation_id: str
    answered: bool


class ProgressRecord(_Record):
    """The RApp's own estimate of how far its task is (rapps.sdk Task.progress)."""

    kind: Literal[RecordKind.PROGRESS]
    agent: str
    fraction: float | None = Field(default=None, ge=0.0, le=1.0)
    text: str = ""


class LogRecord(_Record):
    """A RApp's log line (rapps.sdk Task.log), with the state of its behaviour it was written in."""

    kind: Literal[RecordKind.LOG]
    agent: str
    level: Literal["debug", "info", "warning", "error"]
    message: str
    state: str = ""


class BlackboardRecord(_Record):
    """A write to a RApp's typed blackboard: the key, the value (capped text) and the writer."""

    kind: Literal[RecordKind.BLACKBOARD]
    agent: str
    key: str
    value: str
    writer: str = ""


TraceRecord = Annotated[Union[MessageRecord, StructureRecord, AgentRecord, BehaviourRecord, StateRecord,
                              TimeoutRecord, RetryRecord, ResendRecord, DroppedRecord, DuplicateRecord,
                              ProgressRecord, LogRecord, BlackboardRecord],
                        Field(discriminator="kind")]
_ADAPTER: TypeAdapter[TraceRecord] = TypeAdapter(TraceRecord)


def parse_record(rec: dict[str, Any]) -> TraceRecord:
    """The typed record; pydantic.ValidationError (a ValueError) when `rec` is not one."""
    return _ADAPTER.validate_python(rec)


def is_valid(rec: Any) -> bool:
    try:
        _ADAPTER.validate_python(rec)
    except ValueError:
        return False
    return True
