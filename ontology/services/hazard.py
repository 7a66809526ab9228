"""Hazard-detection checks on a camera image: door opening angle and light level."""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, action
from .common import CameraIntrinsics

GROUP = "vision"

Matrix4 = list[list[float]]


class DoorGeometry(Content):
    """What the geometry method needs besides the image: intrinsics, the camera optical frame in the
    world (4x4, floor is z = 0), and the door's hinge and closed yaw (deg, direction hinge -> latch).
    The original image-only method knew none of it."""

    camera: CameraIntrinsics
    camera_to_world: Matrix4
    hinge: list[float] = Field(min_length=2, max_length=2)  # x, y of the hinge on the floor (m)
    closed_yaw_deg: float
    width_m: float = Field(default=0.9, gt=0)


DoorMethod = Literal["image", "geometry"]


class DoorAngle(Content):
    door_angle: float  # degrees, 0 = closed
    method: DoorMethod  # the method that answered: "geometry" falls back to "image" when it finds no leaf
    # 0..1, how far the answer's evidence can be trusted: image method, whether the floor lines it took
    # pass where the camera looks (the hinge, the image's centre; the 90 deg answer, a half without a
    # line, at most 0.5); geometry method, how much of the leaf's width its segments cover
    confidence: float = Field(default=0.0, ge=0.0, le=1.0)
    lines: list[list[float]] = []  # the image segments it took (x1, y1, x2, y2 px): image method left, right


@action("hazard_detection_door_check", ontology="platform", reply=DoorAngle, group=GROUP, idempotent=True)
class DoorCheck(ServiceRequest):
    """Door opening angle (degrees) from one image of where the door meets the floor.

    "image" (default): the original RAPP method, the angle between the floor lines of the image's
    halves (90 when a half has none). "geometry": the leaf's metric angle on the floor, needs `geometry`."""

    image_b64: str
    method: DoorMethod = "image"
    geometry: DoorGeometry | None = None


class LightLevel(Content):
    light_level: int  # 0..100
    lamp_on: bool
    confidence: float = Field(default=0.0, ge=0.0, le=1.0)  # 0..1: how far the level is from the threshold


@action("hazard_detection_light_check", ontology="platform", reply=LightLevel, group=GROUP, idempotent=True)
class LightCheck(ServiceRequest):
    """Light level 0..100 of the image's centre against its surround (the original RAPP rule).

    Meant for an image taken with a low exposure (the robot's `set_camera_params`)."""

    image_b64: str
    on_threshold: int = Field(default=30, ge=0, le=100)
