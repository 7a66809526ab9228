"""Image and QR-code geometry for RApps: the same functions the Platform's localization service
runs, so a RApp's Cloud part can do its own variant of it from its package alone; and the door
check's floor-line rule (its bound, shortest segment and score), so a RApp can predict what the
check will see from a stand before it goes there.

Poses are 4x4 homogeneous transforms (numpy); `planar(T)` gives (x, y, theta).
"""
from __future__ import annotations

from agents.services.hazard import HORIZONTAL as FLOOR_LINE_RAD
from agents.services.hazard import DoorLineParams, floor_line_score
from agents.services.images import decode_image, encode_image
from agents.services.localization import (camera_matrix, code_corners_3d, code_pose, detect_qr, landmark_transform,
                                          planar, refine_corners, robot_pose_from_code)
from agents.services.transforms import invert, transform

__all__ = ["FLOOR_LINE_RAD", "DoorLineParams", "floor_line_score", "decode_image", "encode_image", "camera_matrix", "code_corners_3d", "code_pose", "detect_qr",
           "invert", "landmark_transform", "planar", "refine_corners", "robot_pose_from_code", "transform"]
