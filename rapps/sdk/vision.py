"""Image and QR-code geometry for RApps: the same functions the Platform's localization service
runs, so a RApp's Cloud part can do its own variant of it from its package alone.

Poses are 4x4 homogeneous transforms (numpy); `planar(T)` gives (x, y, theta).
"""
from __future__ import annotations

from agents.services.images import decode_image, encode_image
from agents.services.localization import (camera_matrix, code_corners_3d, code_pose, detect_qr, invert,
                                          landmark_transform, planar, refine_corners, robot_pose_from_code,
                                          transform)

__all__ = ["decode_image", "encode_image", "camera_matrix", "code_corners_3d", "code_pose", "detect_qr",
           "invert", "landmark_transform", "planar", "refine_corners", "robot_pose_from_code", "transform"]
