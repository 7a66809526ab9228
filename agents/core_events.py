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
    person                      a people detector (the Platform's HOG, agents/services/vision.py) finds
                                someone in the robot's camera image (PersonEvents looks every second
                                while someone subscribes; valid for 2 s). Sent when people come into
                                view, then every 3 s while they stay. Data: count, and of the best
                                detection its bearing_rad from the camera's optical axis (counter-
                                clockwise, from the box centre and the camera's field of view), box
                                [x, y, w, h] in pixels of the image (image_size [w, h]), score, camera.
                                Only what the camera sees: never where people really are.
    bumper / touch              a foot bumper or a head/hand touch sensor pressed or released
                                (agents/core_contacts.py)
On a robot with a depth camera (an Elektron's Kinect) the obstacle events also take the nearest point
ahead of its depth image (agents/core_depth.py): what lies below or above the laser's plane.
"""
from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Awaitable, Callable

from spade.behaviour import PeriodicBehaviour

from ontology.acl import Performative
from ontology.errors import ErrorCode
from ontology.notifications import ONTOLOGY, EventTopic, Notification, Notify, SubscribeEvents
from ontology.registry import Done
from ontology.robot import CaptureImage, GetCameraInfo, GetGlobalPose

from .core_contacts import watch_contacts
from .core_depth import with_depth
from .core_parts import EventsHost, ObstacleEcho
from .errors import Refusal
from .messages import bare
from .responder import Responder
from .services.images import decode_image
from .services.vision import detect_people, distinct_people

log = logging.getLogger("rapp.core")
OBSTACLE_TTL_S, ESTOP_TTL_S, PERSON_TTL_S = 1.0, 5.0, 2.0


class CoreEvents:
    """The Core's member for sensor events: who subscribed to what, and the behaviours that watch.
    `nearest_echo`: the range sensors' nearest reading ahead (RobotCommands.nearest_echo)."""

    warn_distance = 0.5  # m beyond the sensors' minimum range: "something is close"

    def __init__(self, host: EventsHost, nearest_echo: Callable[[], Awaitable[ObstacleEcho | None]]):
        self.host, self.nearest_echo = host, nearest_echo
        self.subscriptions: dict[str, set[str]] = {}  # topic -> subscribed JIDs (only the current Dynamic Agent)

    @property
    def robot(self):
        return self.host.robot

    def service(self) -> Responder:
        return Responder(ONTOLOGY, {"subscribe_events": self._on_subscribe}, performative=Performative.SUBSCRIBE)

    async def _on_subscribe(self, req: SubscribeEvents, ctx) -> Done:
        d = self.host.dynamic
        if d is None or ctx.sender != bare(d.jid) or d.ended.is_set():
            raise Refusal(f"{ctx.sender} is not the current supervisor", ErrorCode.NOT_SUPERVISOR)
        for topic in req.topics:
            self.subscriptions.setdefault(topic, set()).add(ctx.sender)
        if {EventTopic.OBSTACLE, EventTopic.OBSTACLE_CLEAR} & set(req.topics):
            self.host.activate("obstacle-events", ObstacleEvents(self))
        if EventTopic.PERSON in req.topics:
            if "camera" in self.robot.capabilities():
                self.host.activate("person-events", PersonEvents(self))
            else:
                log.info("%s subscribed to person events, but the robot has no camera", ctx.sender)
        watch_contacts(self, req.topics)  # bumper, touch: agents/core_contacts.py
        return Done()

    def end_subscriptions(self) -> None:
        """The Dynamic Agent is gone: nobody is told anything any more."""
        self.subscriptions = {}
        self.host.deactivate("obstacle-events")
        self.host.deactivate("person-events")
        self.host.deactivate("contact-events")

    async def publish(self, topic: EventTopic, ttl_s: float | None, **data) -> Notification | None:
        jids = self.subscriptions.get(topic)
        if not jids:
            return None
        note = Notification.event(topic, ttl_s, **data)
        await self.send_notification(note, jids)
        return note

    async def publish_echo(self, topic: EventTopic, echo: ObstacleEcho) -> Notification | None:
        """An obstacle / obstacle-clear event from a range reading."""
        if not self.subscriptions.get(topic):
            return None
        pose = await self.robot.handle(GetGlobalPose())
        return await self.publish(topic, OBSTACLE_TTL_S, margin_m=round(echo.margin_m, 3),
                                  range_m=round(echo.range_m, 3), bearing_rad=round(echo.bearing_rad, 3),
                                  pose=[round(pose.x, 3), round(pose.y, 3), round(pose.theta, 4)])

    async def send_notification(self, note: Notification, jids) -> None:
        for jid in list(jids):
            try:
                await self.host.notify(jid, Notify(notification=note), ontology=ONTOLOGY, action="notification")
            except Exception as e:  # noqa: BLE001 - one unreachable subscriber must not stop the others
                log.warning("notification %s to %s failed: %s", note.topic, jid, e)


class ObstacleEvents(PeriodicBehaviour):
    """Tells subscribers when something comes within the warning distance, and when it is gone."""

    def __init__(self, core: CoreEvents):
        super().__init__(period=0.25)
        self.core, self.close = core, False

    async def run(self) -> None:
        echo = await with_depth(self.core.robot, await self.core.nearest_echo())  # agents/core_depth.py
        if echo is None:
            return
        close = echo.margin_m < self.core.warn_distance
        if close != self.close:
            self.close = close
            await self.core.publish_echo(EventTopic.OBSTACLE if close else EventTopic.OBSTACLE_CLEAR, echo)


class PersonEvents(PeriodicBehaviour):
    """Tells subscribers when the robot's camera sees people: the frame of each period goes through the
    Platform's people detector in a thread. An event when people come into view (after `gone_after`
    frames without anyone: one missed detection is not someone leaving and coming back), then one
    every `repeat_s` while they stay; nothing when they leave (the last event expires).

    The Core captures through the robot API directly, as its safety check reads the range sensors:
    it takes no resource lock (agents/locks.py), so the task's own captures and head motions go on;
    the image is whatever the camera sees, pointed wherever the task points the head."""

    RESOLUTION = "320x240"  # a person 4 m away is 115-165 px tall: enough for HOG's window (~100 px per person)
    SMOOTH_PX = 1.2  # sensor noise makes HOG find "people" on doors and QR codes; a slight blur removes them

    def __init__(self, core, period: float = 1.0, repeat_s: float = 3.0, gone_after: int = 2):
        super().__init__(period=period)
        self.core, self.repeat_s, self.gone_after = core, repeat_s, gone_after
        self.absent = gone_after  # frames in a row without anyone (at the start: nobody in view)
        self.sent_at: float | None = None  # monotonic time of the last event
        self.camera = None  # CameraInfo at RESOLUTION (its field of view for the bearings)
        self.failures = 0

    async def run(self) -> None:
        seen = await self.look()
        if seen is None:
            return
        people, image = seen
        if not people:
            self.absent += 1
            return
        now = time.monotonic()
        arrived, self.absent = self.absent >= self.gone_after, 0
        if not arrived and self.sent_at is not None and now - self.sent_at < self.repeat_s:
            return
        self.sent_at = now
        score, (x, y, w, h) = people[0]
        K = self.camera.K  # bearing of the box centre from the optical axis, positive to the left
        bearing = math.atan2(K[0][2] - (x + w / 2), K[0][0])
        await self.core.publish(EventTopic.PERSON, PERSON_TTL_S, count=len(people), bearing_rad=round(bearing, 3),
                                box=[x, y, w, h], image_size=[image.width, image.height], score=round(score, 2),
                                camera=image.camera)

    async def look(self):
        """(people, the Image) of one frame, people as (score, (x, y, w, h)) best first; None when the
        camera could not be read (logged, tried again next period)."""
        try:
            if self.camera is None:
                self.camera = await self.core.robot.handle(GetCameraInfo(resolution=self.RESOLUTION))
            image = await self.core.robot.handle(CaptureImage(resolution=self.RESOLUTION))
            people = await asyncio.to_thread(self._detect, image.data_b64)
        except Exception as e:  # noqa: BLE001 - a failed frame (render error, robot shutting down) is skipped
            self.failures += 1
            log.log(logging.WARNING if self.failures == 1 else logging.DEBUG, "person events: no frame: %s", e)
            return None
        return people, image

    def _detect(self, data_b64: str) -> list:
        return distinct_people(detect_people(decode_image(data_b64, "image"), smooth=self.SMOOTH_PX))
