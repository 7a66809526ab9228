"""Vision services: face and human detection, object learn / find / clear (QR: localization.py)."""
from __future__ import annotations

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, Done, action

GROUP = "vision"


class Box(Content):
    x: int
    y: int
    width: int
    height: int


class Detections(Content):
    boxes: list[Box]


@action("face_detection", ontology="platform", reply=Detections, group=GROUP, idempotent=True)
class FaceDetect(ServiceRequest):
    image_b64: str


@action("human_detection", ontology="platform", reply=Detections, group=GROUP, idempotent=True)
class HumanDetect(ServiceRequest):
    image_b64: str


@action("object_detection_learn_object", ontology="platform", reply=Done, group=GROUP)
class LearnObject(ServiceRequest):
    name: str = Field(min_length=1, max_length=64)
    image_b64: str


class FoundObject(Content):
    name: str
    matches: int
    corners: list[list[float]]  # the model image's outline in the query image (px)


class FoundObjects(Content):
    objects: list[FoundObject]


@action("object_detection_find_objects", ontology="platform", reply=FoundObjects, group=GROUP, idempotent=True)
class FindObjects(ServiceRequest):
    image_b64: str
    limit: int = Field(default=5, ge=1, le=50)
    min_matches: int = Field(default=15, ge=4)


@action("object_detection_clear_models", ontology="platform", reply=Done, group=GROUP)
class ClearObjects(ServiceRequest):
    pass
