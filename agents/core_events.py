"""The Core's sensor events for its Dynamic Agent (paper 003's typed notifications, ontology/
notifications.py): the supervising Dynamic Agent subscribes (FIPA subscribe) to topics; the Core
sends each matching Notification one way. Subscriptions end with the Dynamic Agent.

    obstacle / obstacle-clear   the range sensors' nearest margin crosses `warn_distance` (checked by
                                ObstacleEvents every 0.25 s while someone subscribes; valid for 1 s).
                                Data: margin_m (beyond the sensor's minimum range), range_m and
                                bearing_rad of the nearest reading ahead (within ±30°), and `pose`, the
                                robot's own pose estimate then ([x, y, theta], get_global_pose): where
                                the obstacle is (obstacle) or up to where the way is free (obstacle-clear)
    estop                       the emergency stop latched or was released (valid for 5 s)
"""
from __future__ import annotations

import logging

from spade.behaviour import PeriodicBehaviour

from ontology.acl import Performative
from ontology.errors import ErrorCode
from ontology.notifications import ONTOLOGY, EventTopic, Notification, Notify, SubscribeEvents
from ontology.registry import Done
from ontology.robot import GetGlobalPose

from .errors import Refusal
from .messages import bare
from .responder import Responder

log = logging.getLogger("rapp.core")
OBSTACLE_TTL_S, ESTOP_TTL_S = 1.0, 5.0


class CoreEvents:
    """Mixed into CoreAgent (which provides `dynamic`, `notify`, `activate`, `deactivate`, `robot`,
    `nearest_echo`, and sets `subscriptions = {}` at construction)."""

    warn_distance = 0.5  # m beyond the sensors' minimum range: "something is close"
    subscriptions: dict[str, set[str]]  # topic -> subscribed JIDs (only the current Dynamic Agent)

    def _events_service(self) -> Responder:
        return Responder(ONTOLOGY, {"subscribe_events": self._on_subscribe}, performative=Performative.SUBSCRIBE)

    async def _on_subscribe(self, req: SubscribeEvents, ctx) -> Done:
        d = self.dynamic
        if d is None or ctx.sender != bare(d.jid) or d.ended.is_set():
            raise Refusal(f"{ctx.sender} is not the current supervisor", ErrorCode.NOT_SUPERVISOR)
        for topic in req.topics:
            self.subscriptions.setdefault(topic, set()).add(ctx.sender)
        if {EventTopic.OBSTACLE, EventTopic.OBSTACLE_CLEAR} & set(req.topics):
            self.activate("obstacle-events", ObstacleEvents(self))
        return Done()

    def end_subscriptions(self) -> None:
        """The Dynamic Agent is gone: nobody is told anything any more."""
        self.subscriptions = {}
        self.deactivate("obstacle-events")

    async def publish(self, topic: EventTopic, ttl_s: float | None, **data) -> Notification | None:
        jids = self.subscriptions.get(topic)
        if not jids:
            return None
        note = Notification.event(topic, ttl_s, **data)
        await self.send_notification(note, jids)
        return note

    async def publish_echo(self, topic: EventTopic, echo) -> Notification | None:
        """An obstacle / obstacle-clear event from a range reading (agents/core_commands.ObstacleEcho)."""
        if not self.subscriptions.get(topic):
            return None
        pose = await self.robot.handle(GetGlobalPose())
        return await self.publish(topic, OBSTACLE_TTL_S, margin_m=round(echo.margin_m, 3),
                                  range_m=round(echo.range_m, 3), bearing_rad=round(echo.bearing_rad, 3),
                                  pose=[round(pose.x, 3), round(pose.y, 3), round(pose.theta, 4)])

    async def send_notification(self, note: Notification, jids) -> None:
        for jid in list(jids):
            try:
                await self.notify(jid, Notify(notification=note), ontology=ONTOLOGY, action="notification")
            except Exception as e:  # noqa: BLE001 - one unreachable subscriber must not stop the others
                log.warning("notification %s to %s failed: %s", note.topic, jid, e)


class ObstacleEvents(PeriodicBehaviour):
    """Tells subscribers when something comes within the warning distance, and when it is gone."""

    def __init__(self, core):
        super().__init__(period=0.25)
        self.core, self.close = core, False

    async def run(self) -> None:
        echo = await self.core.nearest_echo()
        if echo is None:
            return
        close = echo.margin_m < self.core.warn_distance
        if close != self.close:
            self.close = close
            await self.core.publish_echo(EventTopic.OBSTACLE if close else EventTopic.OBSTACLE_CLEAR, echo)
