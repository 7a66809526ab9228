"""What a run's recording holds beside its trace (docs/recordings.md).

- `messages.jsonl` (agents/tracing.py BODIES): one BodyRecord per message and side where a recording
  was asked for: the whole body, secrets replaced by placeholders (`<secret:...>`, stable within the
  writing process), written by trusted agents and, for a RApp process, by its trusted relay (then
  with `origin`, the RApp's JID, as in the trace).
- `robot.jsonl` (scenarios/recording.py): what the simulated robot did and sensed, written by the
  scenario's process: RobotSample records (true and estimated poses, planned paths, laser and sonar
  scans, camera frames), each with the wall clock (`t`, as the trace's) and the simulation's (`sim`).
- `packages/<sha256>.rapp`: every RApp package a recorded Core ran.
- `run.mcap`: all of it for Foxglove, Lichtblick and other MCAP readers (scenarios/mcap_export.py);
  its ACL channels carry AclMessage, whose JSON Schema is the channels' schema.
"""
from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

from .trace import Direction


class BodyRecord(BaseModel):
    """A message's whole body as one side saw it (the trace's message record has it capped)."""

    model_config = ConfigDict(extra="allow", frozen=True)

    t: float
    kind: Literal["body"]
    pid: int
    dir: Direction
    agent: str
    sender: str
    receiver: str
    performative: str  # a FIPA performative, or "chat"
    conversation_id: str
    ontology: str
    action: str
    message_id: str
    in_reply_to: str
    feedback: bool = False
    body: str
    origin: str = ""  # set by a relay: a RApp process wrote it


class AclMessage(BaseModel):
    """An ACL message as an MCAP channel carries it: the FIPA fields and the content, parsed where it
    is JSON (so a reader can plot its fields), else the text."""

    sender: str
    receiver: str
    performative: str
    conversation_id: str
    ontology: str = ""
    action: str = ""
    message_id: str = ""
    in_reply_to: str = ""
    feedback: bool = False
    size: int = 0
    content: Any = None
    truncated: bool = False  # the content is the trace's capped text, not the whole body


SampleKind = Literal["pose", "estimate", "path", "laser", "sonar", "image", "map", "clock"]


class RobotSample(BaseModel):
    """One line of robot.jsonl: `t` wall clock (s since the epoch), `sim` simulation time (s)."""

    model_config = ConfigDict(extra="allow")

    t: float
    sim: float
    kind: SampleKind
    robot: str = ""
