"""A depth image's encoding (robots/depth_camera.py, ontology.robot.DepthImage): a 16-bit PNG of millimetres,
0 = no return, as ROS's 16UC1 depth images; importable without the simulator (a Core reads it)."""
from __future__ import annotations

import numpy as np


def encode_depth(z: np.ndarray) -> bytes:
    """A 16-bit PNG of millimetres (0 = no return), as ROS's 16UC1 depth images."""
    import cv2
    ok, buf = cv2.imencode(".png", np.clip(np.round(z * 1000.0), 0, 65535).astype(np.uint16))
    return buf.tobytes()


def decode_depth(data: bytes) -> np.ndarray:
    """Metres (float32, 0 = no return) from encode_depth's PNG."""
    import cv2
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype != np.uint16 or img.ndim != 2:
        raise ValueError("not a 16-bit single-channel PNG")
    return img.astype(np.float32) / 1000.0
