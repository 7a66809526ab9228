"""The Core's sensor events (agents/core_events.py): obstacle / obstacle-clear on crossings only, person
when the camera's people detector finds someone, and the typed notification's expiry
(ontology/notifications.py)."""
import asyncio
import time
from types import SimpleNamespace

import pytest
from pydantic import ValidationError

from agents.core_parts import ObstacleEcho
from agents.core_events import ObstacleEvents, PersonEvents
from ontology.notifications import EventTopic, Notification, NotificationKind, SubscribeEvents


class _Core:
    warn_distance = 0.5

    def __init__(self, readings):
        self.readings, self.sent = list(readings), []
        self.robot = SimpleNamespace(capabilities=frozenset)  # no depth camera: the range sensors alone

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


# --- person events: a real world and robot API, a stand-in Core that records what it publishes --------
class _Watcher:
    def __init__(self, robot):
        self.robot, self.published = robot, []

    async def publish(self, topic, ttl_s, **data):
        self.published.append((topic, ttl_s, data))


async def test_person_events_when_someone_comes_into_view_then_every_few_seconds():
    from robots import RobotAPI, World

    # the person waits behind the closed bedroom door, then walks in and stands 2.5 m ahead of an
    # Elektron, 0.4 m to its left
    walk_in = {"kind": "person", "id": "visitor", "start": 1.0, "speed": 1.5,
               "route": [[4.6, 1.45], [3.1, 1.45], [3.1, 2.4]]}
    world = World.from_file("small", seed=1, overrides={"doors": {"d1": 0}}, render="inline", disturbances=[walk_in])
    try:
        core = _Watcher(RobotAPI(world.add_robot("elektron", pose=(0.6, 2.0, 0.0))))
        watch = PersonEvents(core, repeat_s=3.0)  # a detection takes up to ~0.4 s on a loaded machine
        await watch.run()
        assert core.published == []  # nobody in view
        await world.sleep(1.0 + (1.5 + 0.95) / 1.5 + 0.2 - world.time)
        await watch.run()
        assert len(core.published) == 1, core.published
        topic, ttl, data = core.published[0]
        assert (topic, ttl, data["count"], data["camera"], data["image_size"]) == (EventTopic.PERSON, 2.0, 1, "head", [320, 240])
        assert 0.08 < data["bearing_rad"] < 0.25  # left of the optical axis: atan(0.4 / 2.56) = 0.155
        x, y, w, h = data["box"]
        assert x + w / 2 < 160 and h > 150, data  # left of the centre, most of the picture's height
        await watch.run()
        assert len(core.published) == 1  # still in view: not again at once
        await asyncio.sleep(3.0)
        await watch.run()
        assert len(core.published) == 2 and core.published[1][2]["count"] == 1  # ... but after repeat_s
    finally:
        world.close()


class EventsHost:
    """What CoreEvents needs of the Core (agents/core_parts.py EventsHost), nothing else; behaviours
    it starts are kept, not run."""

    def __init__(self, robot):
        from types import SimpleNamespace
        self.robot, self.active = robot, {}
        self.dynamic = SimpleNamespace(jid="dyn-1@localhost/r", ended=asyncio.Event())

    def activate(self, name, behaviour, template=None):
        self.active.setdefault(name, behaviour)

    def deactivate(self, name):
        self.active.pop(name, None)


async def no_echo():
    return None


async def test_subscribing_to_person_starts_the_camera_watch_and_the_task_end_stops_it():
    from types import SimpleNamespace

    from agents.core_events import CoreEvents
    from robots import RobotAPI, World

    world = World.from_file("small", seed=1, render="inline")
    try:
        host = EventsHost(RobotAPI(world.add_robot("nao")))
        events = CoreEvents(host, no_echo)
        await events._on_subscribe(SubscribeEvents(topics=["estop"]), SimpleNamespace(sender="dyn-1@localhost"))
        assert host.active == {}
        await events._on_subscribe(SubscribeEvents(topics=["person"]), SimpleNamespace(sender="dyn-1@localhost"))
        assert isinstance(host.active.get("person-events"), PersonEvents)
        assert events.subscriptions == {"estop": {"dyn-1@localhost"}, "person": {"dyn-1@localhost"}}
        events.end_subscriptions()
        assert host.active == {} and events.subscriptions == {}
    finally:
        world.close()
