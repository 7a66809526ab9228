"""Hazard-detection checks on a camera image: door opening angle and light level."""
from __future__ import annotations

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, action
from .common import CameraIntrinsics

GROUP = "vision"

Matrix4 = list[list[float]]


class DoorGeometry(Content):
    """Optional geometry making the door angle metric: intrinsics, the camera optical frame in the
    world (4x4, floor is z = 0), and the door's hinge and closed yaw (deg, direction hinge -> latch)."""

    camera: CameraIntrinsics
    camera_to_world: Matrix4
    hinge: list[float] = Field(min_length=2, max_length=2)  # x, y of the hinge on the floor (m)
    closed_yaw_deg: float
    width_m: float = Field(default=0.9, gt=0)


class DoorAngle(Content):
    door_angle: float  # degrees, 0 = closed
    method: str  # "geometry" or "image"


@action("hazard_detection_door_check", ontology="platform", reply=DoorAngle, group=GROUP, idempotent=True)
class DoorCheck(ServiceRequest):
    image_b64: str
    geometry: DoorGeometry | None = None


class LightLevel(Content):
    light_level: int  # 0..100
    lamp_on: bool


@action("hazard_detection_light_check", ontology="platform", reply=LightLevel, group=GROUP, idempotent=True)
class LightCheck(ServiceRequest):
    image_b64: str
    on_threshold: int = Field(default=30, ge=0, le=100)
