"""Command interpretation: free text -> the RApp to run and its parameters, and, when the owner
names a time ("every day at 22:00", "in ten minutes", "cancel the evening check"), what to
schedule (paper 000 sec. 7: the hazard check runs on a request or as a scheduled task)."""
from __future__ import annotations

from enum import StrEnum
from typing import Literal

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, action


class RAppDescription(Content):
    name: str
    keywords: list[str] = []
    phrases: list[str] = []
    robot_types: list[str] = []  # empty = any robot


class ScheduleAction(StrEnum):
    ADD = "add"  # run the RApp at the time said
    CANCEL = "cancel"  # forget the schedules that fit what was said
    LIST = "list"  # tell the schedules kept


class When(Content):
    """A time as the owner said it; the robot's Core resolves it against its own clock and zone
    (the Platform cannot know the robot's time: a simulated one runs at its own pace)."""

    kind: Literal["at", "in", "daily"]
    hour: int | None = Field(None, ge=0, le=23)  # at, daily: the time of day, local to the robot
    minute: int = Field(0, ge=0, le=59)
    day: Literal["today", "tomorrow"] | None = None  # at: said; None: the next such time
    date: str | None = Field(None, pattern=r"^\d{4}-\d{2}-\d{2}$")  # at: a day said as YYYY-MM-DD
    seconds: float | None = Field(None, ge=0)  # in: from now


class ScheduleRequest(Content):
    """What a command asks of the Core's schedules (Interpretation.schedule)."""

    action: ScheduleAction
    when: When | None = None  # add: when; cancel: only the schedules at that time of day
    part_of_day: Literal["morning", "afternoon", "evening", "night"] | None = None  # cancel: "the evening check"
    every: bool = False  # cancel: all that fit ("cancel all the checks"), not only one


class Interpretation(Content):
    rapp: str = Field("", description="the RApp; '' only for a schedule's cancel or list naming none")
    parameters: dict[str, str] = {}
    score: float
    matched: list[str] = []
    schedule: ScheduleRequest | None = None  # a time was named: keep, cancel or list schedules


@action("interpret_command", ontology="platform", reply=Interpretation, group="speech", idempotent=True)
class InterpretCommand(ServiceRequest):
    """Which RApp a spoken or typed command asks for, with its parameters' values."""

    text: str = Field(min_length=1, max_length=1000)
    robot_type: str = ""
    rapps: list[RAppDescription] = Field(min_length=1)
