"""A simulated person is human-shaped (robots/disturbances.py person_parts), so the Platform's HOG people
detector (agents/services/vision.py, with the Core's settings) finds them in a robot's camera image, and
finds nobody when they are not in view. Default failure modes: camera noise, auto-exposure, JPEG frames.

The robot looks at the person from close by (NAO 1.5 m, Elektron 2.4 m): the frame cuts the person
(legs or head), where the earlier body (a cylinder with a ball for a head) was found weakly or not at
all; from 3 m on, where the whole body is in the frame, the detector finds either."""
import base64

import cv2
import numpy as np
import pytest

from agents.core_events import PersonEvents
from agents.services.vision import detect_people, distinct_people
from ontology.robot import CaptureImage, LookAtPoint

from .conftest import api_at

# The person waits in the bedroom, behind the closed door, then walks into the living room and stops
# in front of the robot, seen from the side (walking north).
FRONT = (3.1, 2.0)
WALK_IN = {"kind": "person", "id": "visitor", "start": 1.0, "speed": 1.5,
           "route": [[4.6, 1.45], [3.1, 1.45], list(FRONT)]}
ARRIVED_S = 1.0 + (1.5 + 0.55) / 1.5 + 0.2


async def people_in(api) -> list:
    reply = await api.capture_image(CaptureImage(resolution="320x240"))
    img = cv2.imdecode(np.frombuffer(base64.b64decode(reply.data_b64), np.uint8), cv2.IMREAD_COLOR)
    return distinct_people(detect_people(img, smooth=PersonEvents.SMOOTH_PX))


@pytest.mark.parametrize("kind,distance", [("nao", 1.5), ("elektron", 2.4)])
async def test_a_person_walking_into_view_is_detected_and_nobody_before(make_world, kind, distance):
    world = make_world("small", overrides={"doors": {"d1": 0}}, disturbances=[WALK_IN])
    api = api_at(world, kind, (FRONT[0] - distance, FRONT[1], 0))
    assert await people_in(api) == []  # the person is behind the closed door
    await api.look_at_point(LookAtPoint(x=1.8, y=3.95, z=0.7))  # a QR code on a plain wall: nobody either
    assert await people_in(api) == []
    await api.look_at_point(LookAtPoint(x=FRONT[0], y=FRONT[1], z=0.85))
    await world.sleep(ARRIVED_S - world.time)
    assert world.ground_truth().movers["visitor"][:2] == pytest.approx(FRONT)
    people = await people_in(api)
    assert len(people) == 1, people
    score, (x, y, w, h) = people[0]
    assert score > 1.0, people  # a confident detection (the cylinder body scored 0.7 at most here)
    assert abs(x + w / 2 - 160) < 25 and h > 180  # in the middle of the picture, most of its height
