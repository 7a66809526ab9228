"""Shared pieces of service messages: poses and images."""
from __future__ import annotations

from pydantic import Field

from ..registry import Content


class Pose2D(Content):
    """Planar pose in the global (map) frame: metres and radians."""

    x: float
    y: float
    theta: float = 0.0


class CameraIntrinsics(Content):
    """Pinhole intrinsics in pixels; `dist` are OpenCV distortion coefficients (may be empty)."""

    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float
    dist: list[float] = []
