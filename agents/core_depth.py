"""The obstacle events' depth reading (agents/core_events.py ObstacleEvents): on a robot with a depth camera
(the Elektron's bottom Kinect, robots/elektron.py) the nearest point ahead that stands off the floor, beside
the range sensors' nearest reading. The laser scans one plane 0.26 m above the floor: a toy, a dropped box
or a low step below it, or a table top above it, is seen by the depth camera only.

A point counts when it is above FLOOR_M (the floor's own points, with the sensor's noise, stay below) and
below HEIGHT_M (higher, the robot passes under it), within ±30° of the heading as the range readings'; its
margin is its horizontal distance from the camera's mount, as a laser's range is from the scanner.
"""
from __future__ import annotations

import asyncio
import base64
import logging
import math

import numpy as np

from ontology.robot import CaptureDepth, DepthImage
from robots.depth_png import decode_depth
from robots.errors import RobotError

from .core_parts import AHEAD_RAD, ObstacleEcho


log = logging.getLogger("rapp.core")
RESOLUTION = "160x120"  # a 3 cm box 2 m ahead still covers a few pixels; a quarter of QVGA's rendering
FLOOR_M, HEIGHT_M = 0.06, 1.2


def nearest_point(img: DepthImage) -> ObstacleEcho | None:
    """The nearest obstacle point ahead in a depth image, None when there is none."""
    z = decode_depth(base64.b64decode(img.data_b64))
    K, T = np.asarray(img.K), np.asarray(img.camera_to_robot)
    v, u = np.nonzero(z > 0)
    d = z[v, u].astype(np.float64)
    cam = np.stack([(u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d, d])
    x, y, h = T[:3, :3] @ cam + T[:3, 3:4]
    keep = (h > FLOOR_M) & (h < HEIGHT_M) & (np.abs(np.arctan2(y, x)) <= AHEAD_RAD)
    if not keep.any():
        return None
    margin = np.hypot(x[keep] - T[0, 3], y[keep] - T[1, 3])
    i = int(np.argmin(margin))
    px, py = float(x[keep][i]), float(y[keep][i])
    return ObstacleEcho(float(margin[i]), math.hypot(px, py), math.atan2(py, px))


async def with_depth(robot, echo):
    """`echo` (the range sensors' nearest reading, an ObstacleEcho), or the depth camera's nearest point
    when nearer."""
    if "depth" not in robot.capabilities():
        return echo
    try:
        img = await robot.handle(CaptureDepth(resolution=RESOLUTION))
        seen = await asyncio.to_thread(nearest_point, img)
    except (RobotError, ValueError) as e:  # a failed frame: the range sensors alone this time
        log.debug("depth reading failed: %s", e)
        return echo
    return seen if seen is not None and (echo is None or seen.margin_m < echo.margin_m) else echo
