"""Hazard checks (after the original RAPP algorithms, see docs in rapp-original.md):

- light level: mean intensity of a central square vs. eight surrounding squares (corners small,
  edge midpoints medium, centre large); min, max and the centre are dropped from the surround, the
  difference is scaled by 4 and clamped to 0..100. Resolution-independent.
- door angle, image only: adaptive threshold, probabilistic Hough lines, best near-horizontal line
  in the left and in the right half (angle / position / length score), angle between them.
- door angle with geometry: the Hough segments are back-projected to the floor (z = 0) with the
  camera intrinsics and pose; segments lying along the door leaf's bottom edge (starting near the
  hinge) give the leaf direction; the angle to the closed direction is the opening angle.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from ontology.services.hazard import DoorAngle, DoorCheck, DoorGeometry, LightCheck, LightLevel
from ontology.errors import ErrorCode

from .context import ServiceContext
from .errors import ServiceError
from .images import decode_image


def light_level(gray: np.ndarray) -> int:
    """0..100: how much brighter the centre of the image is than its surround."""
    h, w = gray.shape
    g = gray.astype(np.float64)

    def mean(cx, cy, half):  # square centred at (cx, cy) in fractions of the image
        x0, x1 = int((cx - half) * w), int(math.ceil((cx + half) * w))
        y0, y1 = int((cy - half) * h), int(math.ceil((cy + half) * h))
        return float(g[max(0, y0):y1, max(0, x0):x1].mean())

    centre = mean(0.5, 0.5, 0.15)
    corners = [mean(x, y, 0.05) for x in (0.1, 0.9) for y in (0.1, 0.9)]
    edges = [mean(0.5, 0.12, 0.08), mean(0.5, 0.88, 0.08), mean(0.12, 0.5, 0.08), mean(0.88, 0.5, 0.08)]
    surround = sorted(corners + edges)[1:-1]  # drop min and max
    diff = (centre - float(np.mean(surround))) * 4.0 * 100.0 / 255.0
    return int(np.clip(round(diff), 0, 100))


def light_check(req: LightCheck, ctx: ServiceContext) -> LightLevel:
    level = light_level(decode_image(req.image_b64, gray=True))
    return LightLevel(light_level=level, lamp_on=level >= req.on_threshold)


def hough_segments(gray: np.ndarray) -> np.ndarray:
    """(n, 4) segments x1, y1, x2, y2 from adaptive threshold + probabilistic Hough."""
    h, w = gray.shape
    block = max(3, (min(h, w) // 20) | 1)
    binary = cv2.adaptiveThreshold(cv2.GaussianBlur(gray, (5, 5), 0), 255, cv2.ADAPTIVE_THRESH_MEAN_C,
                                   cv2.THRESH_BINARY, block, 5)
    edges = cv2.Canny(binary, 50, 150)
    lines = cv2.HoughLinesP(edges, 1, np.pi / 360, threshold=max(20, w // 20),
                            minLineLength=max(15, w // 12), maxLineGap=max(3, w // 80))
    return np.zeros((0, 4)) if lines is None else lines.reshape(-1, 4).astype(np.float64)


def _seg_angle(s) -> float:
    """Angle of a segment in degrees, in (-90, 90]."""
    a = math.degrees(math.atan2(s[3] - s[1], s[2] - s[0]))
    return a - 180 if a > 90 else a + 180 if a <= -90 else a


def door_angle_image(gray: np.ndarray, max_tilt: float = 45.0) -> float:
    """Original image-only estimate: best near-horizontal line in each half, angle between them."""
    h, w = gray.shape
    best = {}
    for s in hough_segments(gray):
        ang = _seg_angle(s)
        if abs(ang) > max_tilt:
            continue
        mx, my = (s[0] + s[2]) / 2, (s[1] + s[3]) / 2
        side = "left" if mx < w / 2 else "right"
        length = math.hypot(s[2] - s[0], s[3] - s[1])
        score = length / w + 0.5 * (my / h) - 0.3 * abs(ang) / max_tilt  # long, low, flat lines win
        if side not in best or score > best[side][0]:
            best[side] = (score, ang)
    if len(best) < 2:
        return 0.0 if best else 0.0
    return abs(best["left"][1] - best["right"][1])


def floor_points(pix: np.ndarray, geo: DoorGeometry) -> np.ndarray:
    """Back-project pixels (n, 2) to the floor plane z = 0 of the world; NaN where the ray misses."""
    K = np.array([[geo.camera.fx, 0, geo.camera.cx], [0, geo.camera.fy, geo.camera.cy], [0, 0, 1]])
    T = np.asarray(geo.camera_to_world, float)
    rays = (T[:3, :3] @ (np.linalg.inv(K) @ np.c_[pix, np.ones(len(pix))].T)).T
    o = T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -o[2] / rays[:, 2]
    pts = o[None, :2] + s[:, None] * rays[:, :2]
    pts[~(s > 0)] = np.nan
    return pts


def door_angle_geometry(gray: np.ndarray, geo: DoorGeometry) -> float | None:
    """Opening angle from floor-projected segments that start at the hinge and run along the leaf."""
    segs = hough_segments(gray)
    if len(segs) == 0:
        return None
    a = floor_points(segs[:, :2], geo)
    b = floor_points(segs[:, 2:], geo)
    hinge = np.asarray(geo.hinge, float)
    closed = math.radians(geo.closed_yaw_deg)
    nadir = np.asarray(geo.camera_to_world, float)[:2, 3]
    votes, weights = [], []
    for p, q in zip(a, b):
        if np.isnan(p).any() or np.isnan(q).any():
            continue
        near, far = (p, q) if np.linalg.norm(p - hinge) < np.linalg.norm(q - hinge) else (q, p)
        length = float(np.linalg.norm(far - near))
        if length < 0.15 or np.linalg.norm(far - hinge) > geo.width_m + 0.05:
            continue
        d = (far - near) / length
        radial = near - nadir  # vertical edges back-project along rays from the camera's nadir
        if abs(radial[0] * d[1] - radial[1] * d[0]) / max(np.linalg.norm(radial), 1e-9) < math.sin(math.radians(6)):
            continue
        # distance of the hinge from the segment's line: the leaf's bottom edge passes the hinge
        off = abs((hinge - near)[0] * d[1] - (hinge - near)[1] * d[0])
        if off > 0.08:
            continue
        yaw = math.atan2(*(far - hinge)[::-1])
        ang = abs(math.degrees(math.atan2(math.sin(yaw - closed), math.cos(yaw - closed))))
        if ang <= 95:
            votes.append(ang)
            weights.append(length)
    if not votes:
        return None
    return float(np.average(votes, weights=weights))


def door_check(req: DoorCheck, ctx: ServiceContext) -> DoorAngle:
    gray = decode_image(req.image_b64, gray=True)
    if req.geometry is not None:
        T = np.asarray(req.geometry.camera_to_world, float)
        if T.shape != (4, 4):
            raise ServiceError("geometry.camera_to_world must be a 4x4 matrix", ErrorCode.BAD_TRANSFORM)
        angle = door_angle_geometry(gray, req.geometry)
        if angle is not None:
            return DoorAngle(door_angle=round(min(angle, 90.0), 1), method="geometry")
    return DoorAngle(door_angle=round(door_angle_image(gray), 1), method="image")
