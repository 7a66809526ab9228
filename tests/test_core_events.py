"""The Core's sensor events (agents/core_events.py): obstacle / obstacle-clear on crossings only, and
the typed notification's expiry (ontology/notifications.py)."""
import time

import pytest
from pydantic import ValidationError

from agents.core_commands import ObstacleEcho
from agents.core_events import ObstacleEvents
from ontology.notifications import EventTopic, Notification, NotificationKind, SubscribeEvents


class _Core:
    warn_distance = 0.5

    def __init__(self, readings):
        self.readings, self.sent = list(readings), []

    async def nearest_echo(self):
        margin = self.readings.pop(0)
        return None if margin is None else ObstacleEcho(margin, margin + 0.25, 0.44)

    async def publish_echo(self, topic, echo):
        self.sent.append((topic, echo.margin_m))


async def test_obstacle_events_on_crossings_only():
    core = _Core([1.0, 0.4, 0.3, None, 0.45, 0.9, 0.8, 0.2])
    watch = ObstacleEvents(core)
    for _ in range(8):
        await watch.run()
    assert core.sent == [(EventTopic.OBSTACLE, 0.4), (EventTopic.OBSTACLE_CLEAR, 0.9), (EventTopic.OBSTACLE, 0.2)]


def test_notification_stamp_and_expiry():
    n = Notification.event(EventTopic.ESTOP, ttl_s=2.0, latched=True)
    assert n.kind == NotificationKind.EVENT and not n.expired() and n.expired(now=n.stamp + 2.5)
    assert not Notification.event("obstacle").expired(now=time.time() + 1e6)  # no expiry: never stale
    with pytest.raises(ValidationError):
        SubscribeEvents(topics=["person-with-a-hat"])
    with pytest.raises(ValidationError):
        SubscribeEvents(topics=[])
