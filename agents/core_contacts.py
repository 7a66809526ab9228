"""The Core's contact events (ontology/notifications.py "bumper" and "touch"): the robot's contact sensors
(robots/contact_sensors.py: a NAO's foot bumpers, its head and hand touch sensors) read through the robot
API's get_contacts while the supervising Dynamic Agent subscribes, each press and release sent as a typed
notification, as the obstacle events are (agents/core_events.py). The Core takes no lock to read them.

    bumper / touch   data: the fields of ontology.robot.ContactChange (sensor, kind, pressed, stamp in
                     simulation time, seq); valid for CONTACT_TTL_S. Sent in the order they happened; the
                     robot keeps the last CONTACT_BUFFER changes, so a busy Core loses none of a burst.
"""
from __future__ import annotations

import logging

from spade.behaviour import PeriodicBehaviour

from ontology.notifications import EventTopic
from ontology.robot import GetContacts

log = logging.getLogger("rapp.core")
CONTACT_TTL_S = 2.0
TOPICS = {"bumper": EventTopic.BUMPER, "touch": EventTopic.TOUCH}


class ContactEvents(PeriodicBehaviour):
    """Reads the robot's contact sensors every `period` s and publishes what changed since the last read."""

    def __init__(self, events, period: float = 0.1):
        super().__init__(period=period)
        self.core = events  # the Core's CoreEvents: its robot and its publish
        self.after: int | None = None  # the last change published (None: not read yet)
        self.failures = 0

    async def run(self) -> None:
        try:
            reply = await self.core.robot.handle(GetContacts(after=self.after))
        except Exception as e:  # noqa: BLE001 - a failed read (robot shutting down): the next period reads again
            self.failures += 1
            log.log(logging.WARNING if self.failures == 1 else logging.DEBUG, "contact events: no reading: %s", e)
            return
        self.after = reply.last  # the first read only takes the sensors' state: nothing before the subscription
        for change in reply.changes:
            await self.core.publish(TOPICS[change.kind], CONTACT_TTL_S, **change.model_dump())


def watch_contacts(events, topics) -> None:
    """On a subscription to `topics`: the contact watch starts when they hold bumper or touch and the robot
    has such sensors (CoreEvents._on_subscribe; end_subscriptions deactivates it)."""
    wanted = {t for t in (EventTopic.BUMPER, EventTopic.TOUCH) if t in topics}
    if not wanted:
        return
    has = events.robot.capabilities()
    if {"bumpers", "touch"} & has:
        events.host.activate("contact-events", ContactEvents(events))
    else:
        log.info("subscribed to %s events, but the robot has no contact sensors", ", ".join(sorted(wanted)))
