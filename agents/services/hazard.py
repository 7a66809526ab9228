"""Hazard checks, the original RAPP algorithms (rapp_hazard_detection, light_check.cpp and
door_check.cpp of the RAPP Platform; docs/hazard-validation.md measures them on renders):

- light level: mean intensity of a large central square vs. eight surrounding squares (small
  corners, medium edge midpoints) centred on the quarter points of the image; the minimum, the
  maximum and the centre are dropped from the sum of all nine, the difference of the centre to the
  average of the remaining six is scaled by 4 and clamped to 0..100. Meant for an image taken with
  a low exposure, where only light sources stay bright.
- door angle, image only (the default): adaptive threshold, probabilistic Hough segments, the
  best-scoring near-horizontal segment (angle, position, length scores) in the left and in the
  right half, the angle between the two in the image; 90 degrees when a half has none. The camera
  looks at where the door meets the floor.
- door angle with geometry (an option the original did not have, `method="geometry"`): the Hough
  segments are back-projected to the floor (z = 0) with the camera intrinsics and pose; segments
  lying along the door leaf's bottom edge (starting near the hinge) give the leaf direction; the
  angle to the closed direction is the opening angle.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ontology.services.hazard import DoorAngle, DoorCheck, DoorGeometry, LightCheck, LightLevel
from ontology.errors import ErrorCode

from .context import ServiceContext
from .errors import ServiceError
from .images import decode_image


# ---------------------------------------------------------------------------------- light level
def light_regions(width: int, height: int) -> list[tuple[int, int, int, int]]:
    """(x, y, w, h) of the nine squares as light_check.cpp places them (integer arithmetic, sizes
    from the image height): the eight surrounding ones, then the centre."""
    sx, sy = width // 4, height // 4
    small, medium, large = height // 10, height // 6, height // 4

    def centred(x: int, y: int, side: int) -> tuple[int, int, int, int]:
        return x - side // 2, y - side // 2, side, side

    return [centred(sx, sy, small), centred(sx, 2 * sy, medium), centred(sx, 3 * sy, small),
            centred(2 * sx, sy, medium), centred(2 * sx, 3 * sy, medium),
            centred(3 * sx, sy, small), centred(3 * sx, 2 * sy, medium), centred(3 * sx, 3 * sy, small),
            centred(2 * sx, 2 * sy, large)]


def light_level(img: np.ndarray) -> int:
    """0..100: how much brighter the centre of the image is than its surround (light_check.cpp).
    A colour image is read as the original read it: cv::mean(img)[0], the first (blue) channel of
    a BGR image."""
    plane = img[:, :, 0] if img.ndim == 3 else img
    h, w = plane.shape
    values = [float(plane[y:y + s, x:x + s].mean()) for x, y, s, _ in light_regions(w, h)]
    centre = values[-1]
    # min and max are taken over all nine: a centre brighter than every surround square is dropped
    # twice (as in the original), which only pushes a lit lamp further up to the clamp
    surround = (sum(values) - min(values) - max(values) - centre) / 6
    return int(min(max((centre - surround) * 4, 0.0), 100.0))  # the original returned an int


LIGHT_SURE_LEVELS = 20  # a level this far from the threshold is a sure answer (confidence 1)


def light_check(req: LightCheck, ctx: ServiceContext) -> LightLevel:
    level = light_level(decode_image(req.image_b64))
    return LightLevel(light_level=level, lamp_on=level >= req.on_threshold,
                      confidence=round(min(1.0, abs(level - req.on_threshold) / LIGHT_SURE_LEVELS), 3))


# ------------------------------------------------------------------------- door angle, image
@dataclass(frozen=True)
class DoorLineParams:
    """DoorCheckParams of door_check.hpp ("optimal" defaults), for a 640 px wide image; Hough's
    lengths are scaled with the image width so that other resolutions see the same scene alike."""

    thr_block: int = 3
    thr_c: int = 3
    hough_thr: int = 80
    hough_len: int = 60
    hough_gap: int = 20
    width: int = 640


HORIZONTAL = math.pi / 6  # |angle| below: a floor line candidate
VERTICAL = 2 * math.pi / 6  # |angle| above: a door frame candidate (scored but unused by the angle)
NO_LINE_DEG = 90.0  # the original's answer when a half has no floor line


def door_segments(gray: np.ndarray, params: DoorLineParams = DoorLineParams()) -> np.ndarray:
    """(n, 4) segments x1, y1, x2, y2: adaptive threshold (Gaussian, inverted) + probabilistic Hough."""
    scale = gray.shape[1] / params.width
    binary = cv2.adaptiveThreshold(gray, 255, cv2.ADAPTIVE_THRESH_GAUSSIAN_C, cv2.THRESH_BINARY_INV,
                                   params.thr_block, params.thr_c)
    lines = cv2.HoughLinesP(binary, 1, np.pi / 180, max(1, round(params.hough_thr * scale)),
                            minLineLength=params.hough_len * scale, maxLineGap=params.hough_gap * scale)
    return np.zeros((0, 4)) if lines is None else lines.reshape(-1, 4).astype(np.float64)


def segment_angle(s) -> float:
    """Line.getAngle of the original: atan of the slope, radians in (-pi/2, pi/2] (image y down)."""
    dx, dy = s[2] - s[0], s[3] - s[1]
    return math.pi / 2 if dx == 0 and dy != 0 else math.atan(dy / dx) if dx else 0.0


def floor_line_score(s, width: int, side: str) -> float:
    """The original's score of a near-horizontal segment as the floor line of one half:
    angle (1 = horizontal) x position (1 = centred in the half, 0 in the other half) x length
    (1 = at least half the image width)."""
    angle_score = (math.pi / 2 - abs(segment_angle(s))) / (math.pi / 2)
    mean_x = (s[0] + s[2]) / 2
    cx = (0.25 if side == "left" else 0.75) * width
    position_score = 1.0 - abs(cx - mean_x) / cx
    if (side == "left" and mean_x > 0.5 * width) or (side == "right" and mean_x < 0.5 * width):
        position_score = 0.0
    length_score = min(2 * math.hypot(s[2] - s[0], s[3] - s[1]) / width, 1.0)
    return angle_score * position_score * length_score


def floor_lines(gray: np.ndarray, params: DoorLineParams = DoorLineParams()) -> dict[str, np.ndarray]:
    """The best-scoring floor line of each half that has one ("left", "right" -> segment)."""
    width = gray.shape[1]
    horizontal = [s for s in door_segments(gray, params) if abs(segment_angle(s)) < HORIZONTAL]
    best: dict[str, np.ndarray] = {}
    for side in ("left", "right"):
        top = 0.0
        for s in horizontal:
            score = floor_line_score(s, width, side)
            if score > top:  # a zero score (wrong half) never wins, as in the original
                best[side], top = s, score
    return best


def door_angle_image(gray: np.ndarray, params: DoorLineParams = DoorLineParams()) -> float:
    """Original image-only estimate (degrees): the angle between the floor lines of the two halves
    in the image, 90 when either half has none (the leaf turned away out of the floor line)."""
    return image_answer(gray, params)[0]


CENTRE_TOLERANCE = 0.20  # of the image width: a floor line passing this far from the centre is no evidence


def image_answer(gray: np.ndarray, params: DoorLineParams = DoorLineParams()) -> tuple[float, float, list]:
    """(angle, confidence, lines) of the image-only method. The method assumes the camera looks at
    where the door meets the floor, so both floor lines pass through the image's centre; the
    confidence is how near the worse of the two does (1 through it, 0 at CENTRE_TOLERANCE of the
    width): a far wall's floor line taken for the leaf's is told apart. A 90 deg answer (a half
    without a floor line: a leaf turned far away) is at most half sure, as sure as the other half's
    line is where it should be: nothing shows the leaf. No line at all: 0."""
    lines = floor_lines(gray, params)
    h, w = gray.shape
    near = {side: max(0.0, 1.0 - line_distance(s, (w - 1) / 2, (h - 1) / 2) / (CENTRE_TOLERANCE * w))
            for side, s in lines.items()}
    if len(lines) < 2:
        return NO_LINE_DEG, 0.5 * max(near.values(), default=0.0), [list(map(float, s)) for s in lines.values()]
    angle = abs(math.degrees(segment_angle(lines["left"]) - segment_angle(lines["right"])))
    return angle, min(near.values()), [list(map(float, lines[side])) for side in ("left", "right")]


def line_distance(s, x: float, y: float) -> float:
    """Distance (px) from (x, y) to the infinite line through segment s."""
    dx, dy = s[2] - s[0], s[3] - s[1]
    return abs(dx * (y - s[1]) - dy * (x - s[0])) / max(math.hypot(dx, dy), 1e-9)


# ---------------------------------------------------------------------- door angle, geometry
def hough_segments(gray: np.ndarray) -> np.ndarray:
    """(n, 4) segments x1, y1, x2, y2 for the geometry method: blur, adaptive threshold, Canny and
    probabilistic Hough with lengths relative to the image width."""
    h, w = gray.shape
    block = max(3, (min(h, w) // 20) | 1)
    binary = cv2.adaptiveThreshold(cv2.GaussianBlur(gray, (5, 5), 0), 255, cv2.ADAPTIVE_THRESH_MEAN_C,
                                   cv2.THRESH_BINARY, block, 5)
    edges = cv2.Canny(binary, 50, 150)
    lines = cv2.HoughLinesP(edges, 1, np.pi / 360, threshold=max(20, w // 20),
                            minLineLength=max(15, w // 12), maxLineGap=max(3, w // 80))
    return np.zeros((0, 4)) if lines is None else lines.reshape(-1, 4).astype(np.float64)


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
    found = geometry_answer(gray, geo)
    return None if found is None else found[0]


def geometry_answer(gray: np.ndarray, geo: DoorGeometry) -> tuple[float, float] | None:
    """(angle, confidence) of the geometry method, None when no segment runs along the leaf; the
    confidence is the share of the leaf's width its voting segments cover (up to 1)."""
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
    return float(np.average(votes, weights=weights)), min(1.0, max(weights) / geo.width_m)


def door_check(req: DoorCheck, ctx: ServiceContext) -> DoorAngle:
    """The original image-only method unless the request names "geometry" (with its geometry);
    when the geometry method finds no leaf, the image-only answer is given, and `method` says so."""
    gray = decode_image(req.image_b64, gray=True)
    if req.method == "geometry":
        if req.geometry is None:
            raise ServiceError('method "geometry" needs the geometry field', ErrorCode.BAD_REQUEST)
        if np.asarray(req.geometry.camera_to_world, float).shape != (4, 4):
            raise ServiceError("geometry.camera_to_world must be a 4x4 matrix", ErrorCode.BAD_TRANSFORM)
        found = geometry_answer(gray, req.geometry)
        if found is not None:
            return DoorAngle(door_angle=round(min(found[0], 90.0), 1), method="geometry",
                             confidence=round(found[1], 3))
    angle, confidence, lines = image_answer(gray)
    return DoorAngle(door_angle=round(angle, 1), method="image", confidence=round(confidence, 3), lines=lines)
