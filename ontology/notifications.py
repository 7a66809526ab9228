"""Typed notifications (paper 003): events (something happened), actions (something was done) and
requests (something should be done), each stamped by its sender and valid until it expires.

A Dynamic Agent subscribes to the Core's sensor events with FIPA subscribe (`SubscribeEvents`); the
Core then sends each matching `Notification` as a one-way inform (action "notification"). A receiver
drops (and traces) one that has expired: a stale "obstacle ahead" must not steer a robot that has
moved on, nor a "person" seen seconds ago turn it towards someone who has walked away. Time is the
sender's wall clock (seconds since the epoch), as the trace's.
"""
from __future__ import annotations

import time
from enum import StrEnum
from typing import Any

from pydantic import Field

from .registry import Action, Content, Done, action

ONTOLOGY = "core"


class NotificationKind(StrEnum):
    EVENT = "event"  # something happened (an obstacle appeared, the emergency stop latched)
    ACTION = "action"  # something was done (the robot stopped, a motion was re-issued)
    REQUEST = "request"  # something should be done (by whoever receives it)


class EventTopic(StrEnum):
    """What a RApp can subscribe to on its Core."""

    OBSTACLE = "obstacle"  # the range sensors see something closer than the Core's warning distance
    OBSTACLE_CLEAR = "obstacle-clear"  # ... and later nothing any more
    ESTOP = "estop"  # the emergency stop latched or was released (data: latched, reason, by)
    PERSON = "person"  # a people detector finds someone in the robot's camera image (data: count, bearing_rad, box)
    BUMPER = "bumper"  # a foot bumper was pressed or released (data: ontology.robot.ContactChange's fields)
    TOUCH = "touch"  # a head or hand touch sensor was pressed or released (data: as bumper)


class Notification(Content):
    kind: NotificationKind
    topic: str = Field(min_length=1, max_length=100)
    stamp: float = Field(description="when the sender made it (s since the epoch)")
    expires: float | None = Field(default=None, description="when it stops being true/useful; None: never")
    data: dict[str, Any] = {}

    def expired(self, now: float | None = None) -> bool:
        return self.expires is not None and (time.time() if now is None else now) > self.expires

    @classmethod
    def event(cls, topic: str, ttl_s: float | None = None, **data: Any) -> "Notification":
        now = time.time()
        return cls(kind=NotificationKind.EVENT, topic=topic, stamp=now,
                   expires=None if ttl_s is None else now + ttl_s, data=data)


@action("subscribe_events", ontology=ONTOLOGY, reply=Done, group="task")
class SubscribeEvents(Action):
    """FIPA subscribe from the supervising Dynamic Agent: send me these topics' notifications until I end."""

    topics: list[EventTopic] = Field(min_length=1)


@action("notification", ontology=ONTOLOGY, reply=Done, group="task")
class Notify(Action):
    """The one-way carrier of a Notification (no answer expected)."""

    notification: Notification
