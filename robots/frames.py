"""Poses in PyBullet's terms: a heading as a quaternion, a position and quaternion as a 4x4 pose.
Used by the world's scene, the robots, the things that move and the render processes alike."""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .pybullet_quiet import p


def yaw_quat(yaw: float) -> list[float]:
    """The quaternion (x, y, z, w) of a turn by `yaw` (rad) about the vertical."""
    return [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]


def pose_matrix(pos: Sequence[float], quat: Sequence[float]) -> np.ndarray:
    """The 4x4 homogeneous pose of a position and a quaternion (x, y, z, w)."""
    T = np.eye(4)
    T[:3, :3] = np.array(p.getMatrixFromQuaternion(quat)).reshape(3, 3)
    T[:3, 3] = pos
    return T
