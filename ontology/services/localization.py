"""Localization service messages (paper 001 fig. 6): QR marker detection with 3-D pose, and the
robot's global pose from a detected marker, the camera-to-robot transform and the landmark map."""
from __future__ import annotations

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, action
from .common import CameraIntrinsics, Pose2D

GROUP = "localization"

Matrix4 = list[list[float]]  # row-major homogeneous transform


class QRDetection(Content):
    text: str
    corners: list[list[float]]  # 4 image points (px): code's top-left, top-right, bottom-right, bottom-left
    pose_in_camera: Matrix4 | None = None  # code frame -> camera optical frame (x right, y down, z fwd)
    distance_m: float | None = None


class QRDetections(Content):
    codes: list[QRDetection]


@action("qr_detection", ontology="platform", reply=QRDetections, group="vision", idempotent=True)
class QRDetect(ServiceRequest):
    """Find and decode QR codes; with intrinsics also each code's pose (code frame: origin at the
    code centre, x right, y up on the printed code, z out of its face)."""

    image_b64: str
    camera: CameraIntrinsics | None = None
    code_size_m: float = Field(default=0.16, gt=0)


class Landmark(Content):
    """Global pose of a QR panel centre; yaw (rad) of the panel normal pointing into the room."""

    x: float
    y: float
    z: float
    yaw: float


class MarkerObservation(Content):
    text: str
    pose_in_camera: Matrix4


@action("compute_global_pose", ontology="platform", reply=Pose2D, group=GROUP, idempotent=True)
class ComputeGlobalPose(ServiceRequest):
    """Robot pose from marker observations (averaged over those found in the landmark map)."""

    observations: list[MarkerObservation] = Field(min_length=1)
    camera_to_robot: Matrix4  # camera optical frame -> robot base frame
    landmarks: dict[str, Landmark]
