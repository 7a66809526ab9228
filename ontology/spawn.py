"""What a Core (for a Dynamic Agent) or the Platform (for a Cloud Agent) hands the process it starts.

The spec travels over an inherited pipe, never argv, the environment or a file: it carries the
run's one-time XMPP password (agents/identity.py), which the runtime reads once and forgets.
"""
from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field


class RobotInfo(BaseModel):
    """The robot a Dynamic Agent supervises, as its RApp may know it."""

    robot_id: str
    robot_type: str
    # what the robot has, of robots.interface.CAPABILITIES: speech, microphone, camera, head, sonars, laser,
    # depth, bumpers, touch
    capabilities: list[str] = Field(default_factory=list)


class SpawnSpec(BaseModel):
    kind: Literal["dynamic", "cloud"]
    name: str  # the XMPP account (local part) of this run
    password: str = Field(default="", repr=False)  # one-time, this run's account only
    package_dir: str  # as the child sees it (/app/package in the sandbox)
    platform: str
    core: str = ""  # dynamic: the supervising Core's JID
    owner: str = ""  # cloud: the only JID it serves (its Dynamic Agent)
    token: str = Field(default="", repr=False)  # the run's scoped Platform token
    params: dict[str, Any] = {}
    robot: RobotInfo | None = None
    record: bool = False  # the run is recorded: its agents send their whole message bodies to the trace relay


class WarmLogin(BaseModel):
    """What a warm Cloud worker gets ahead of its run (agents/warm_pool.py, `login=`): an account of
    its own to log in with while idle, so a hand-off costs no login. The run's SpawnSpec follows on
    the same pipe at the hand-off, naming the same account."""

    name: str
    password: str = Field(default="", repr=False)
