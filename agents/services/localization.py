"""QR-marker localization math shared by the Platform services and RApps' Cloud Agents.

Frames: camera optical frame (x right, y down, z forward); code frame (centre of the code, x right,
y up on the printed code, z out of its face, toward the viewer); landmark = panel centre in the world
with yaw of the panel normal (= code +z) pointing into the room; robot frame x forward, z up.
"""
from __future__ import annotations

import math
from collections.abc import Collection

import cv2
import numpy as np

from ontology.services.common import CameraIntrinsics, Pose2D
from ontology.services.localization import (
    ComputeGlobalPose, Landmark, QRDetect, QRDetection, QRDetections,
)
from ontology.errors import ErrorCode

from .context import ServiceContext
from .errors import ServiceError
from .images import decode_image
from .transforms import invert, transform


def camera_matrix(cam: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]], float)
    return K, np.asarray(cam.dist, float) if cam.dist else np.zeros(5)


def code_corners_3d(size: float) -> np.ndarray:
    """Code-frame corners in the detector's order (TL, TR, BR, BL), as IPPE_SQUARE expects."""
    h = size / 2.0
    return np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], np.float64)


def code_pose(corners: np.ndarray, size: float, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """4x4 code -> camera transform from the 4 image corners (solvePnP IPPE_SQUARE)."""
    ok, rvec, tvec = cv2.solvePnP(code_corners_3d(size), corners.reshape(4, 1, 2).astype(np.float64),
                                  K, dist, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    if not ok:
        raise ServiceError("pose estimation of the QR code failed", ErrorCode.POSE_FAILED)
    return transform(cv2.Rodrigues(rvec)[0], tvec)


def refine_corners(gray: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Sub-pixel outer corners: fit a line to each side of the code's dark border (strongest gradient
    along normals sampled on the detected quadrilateral) and intersect adjacent lines."""
    g = cv2.GaussianBlur(gray.astype(np.float32), (3, 3), 0)
    c = corners.reshape(4, 2).astype(np.float64)
    centre = c.mean(axis=0)
    lines = []
    for i in range(4):
        a, b = c[i], c[(i + 1) % 4]
        d = b - a
        length = float(np.hypot(*d))
        if length < 8:
            return c
        n = np.array([-d[1], d[0]]) / length
        if np.dot(centre - a, n) > 0:
            n = -n  # outward normal
        pts = []
        offs = np.linspace(-3.0, 3.0, 61)
        for t in np.linspace(0.12, 0.88, 24):
            p = a + t * d
            samples = p[None, :] + offs[:, None] * n[None, :]
            vals = cv2.remap(g, samples[:, 0:1].astype(np.float32), samples[:, 1:2].astype(np.float32),
                             cv2.INTER_LINEAR).ravel()
            grad = np.gradient(vals)
            k = int(np.argmax(grad))  # dark inside -> bright outside
            if 0 < k < len(offs) - 1 and grad[k] > 5:
                den = grad[k - 1] - 2 * grad[k] + grad[k + 1]
                sub = 0.5 * (grad[k - 1] - grad[k + 1]) / den if den != 0 else 0.0
                pts.append(p + (offs[k] + sub * (offs[1] - offs[0])) * n)
        if len(pts) < 6:
            return c
        pts = np.asarray(pts)
        mean = pts.mean(axis=0)
        _, _, vt = np.linalg.svd(pts - mean)
        lines.append((mean, vt[0]))
    out = []
    for i in range(4):
        (p1, d1), (p2, d2) = lines[(i - 1) % 4], lines[i]
        A = np.array([d1, -d2]).T
        if abs(np.linalg.det(A)) < 1e-6:
            return c
        s = np.linalg.solve(A, p2 - p1)
        out.append(p1 + s[0] * d1)
    out = np.asarray(out)
    return out if np.max(np.hypot(*(out - c).T)) < 4.0 else c


def _decode(det: cv2.QRCodeDetector, img: np.ndarray) -> list[tuple[str, np.ndarray]]:
    # OpenCV 4.14's detector can fail an internal assertion (convexHull) on some frames: for the
    # caller that frame holds no readable code, it is not an error of the request
    try:
        ok, texts, pts, _ = det.detectAndDecodeMulti(img)
    except cv2.error:
        ok, texts, pts = False, (), None
    found = [(t, p.reshape(4, 2)) for t, p in zip(texts, pts) if t] if ok and pts is not None else []
    if not found:  # the single-code path is more tolerant of small codes
        try:
            text, pts, _ = det.detectAndDecode(img)
        except cv2.error:
            text, pts = "", None
        if text and pts is not None:
            found = [(text, pts.reshape(4, 2))]
    return found


STRETCH_X = 2.0  # codes on walls seen obliquely are foreshortened horizontally


def detect_qr(img: np.ndarray, expect: Collection[str] = ()) -> list[tuple[str, np.ndarray]]:
    """(text, 4x2 corners) of each decoded QR code; undecodable codes are skipped.

    OpenCV's detector misses codes seen more than ~50 degrees off their normal, even large ones; a
    second pass on the image stretched horizontally undoes most of that foreshortening (corners
    are mapped back to the original image). That pass costs more than the first (twice the pixels):
    with `expect`, the codes the view was planned for, it runs only when one of them is missing."""
    det = cv2.QRCodeDetector()
    found = dict(_decode(det, img))
    if expect and set(expect) <= found.keys():
        return list(found.items())
    wide = cv2.resize(img, None, fx=STRETCH_X, fy=1.0, interpolation=cv2.INTER_LINEAR)
    for text, pts in _decode(det, wide):
        if text not in found:
            found[text] = (pts + 0.5) * [1.0 / STRETCH_X, 1.0] - [0.5, 0.0]
    return list(found.items())


def landmark_transform(lm: Landmark) -> np.ndarray:
    """Code frame -> world: z along the panel normal (yaw), y up, x = y cross z."""
    z = np.array([math.cos(lm.yaw), math.sin(lm.yaw), 0.0])
    y = np.array([0.0, 0.0, 1.0])
    x = np.cross(y, z)
    return transform(np.column_stack([x, y, z]), [lm.x, lm.y, lm.z])


def robot_pose_from_code(T_cam_code: np.ndarray, T_robot_cam: np.ndarray, lm: Landmark) -> np.ndarray:
    """4x4 robot -> world transform: T_world_code * inv(T_cam_code) * inv(T_robot_cam)."""
    return landmark_transform(lm) @ invert(T_cam_code) @ invert(T_robot_cam)


def planar(T: np.ndarray) -> tuple[float, float, float]:
    return float(T[0, 3]), float(T[1, 3]), math.atan2(T[1, 0], T[0, 0])


def _matrix(rows, what: str) -> np.ndarray:
    T = np.asarray(rows, float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ServiceError(f"{what} must be a finite 4x4 matrix", ErrorCode.BAD_TRANSFORM)
    return T


def qr_detection(req: QRDetect, ctx: ServiceContext) -> QRDetections:
    img = decode_image(req.image_b64)
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    out = []
    for text, corners in detect_qr(img):
        d = QRDetection(text=text, corners=corners.tolist())
        if req.camera is not None:
            K, dist = camera_matrix(req.camera)
            T = code_pose(refine_corners(gray, corners), req.code_size_m, K, dist)
            d.pose_in_camera = T.tolist()
            d.distance_m = float(np.linalg.norm(T[:3, 3]))
        out.append(d)
    return QRDetections(codes=out)


def compute_global_pose(req: ComputeGlobalPose, ctx: ServiceContext) -> Pose2D:
    T_robot_cam = _matrix(req.camera_to_robot, "camera_to_robot")
    poses = []
    for obs in req.observations:
        lm = req.landmarks.get(obs.text)
        if lm is not None:
            poses.append(planar(robot_pose_from_code(_matrix(obs.pose_in_camera, "pose_in_camera"), T_robot_cam, lm)))
    if not poses:
        known = ", ".join(o.text for o in req.observations)
        raise ServiceError(f"none of the observed codes ({known}) is in the landmark map", ErrorCode.UNKNOWN_MARKER)
    p = np.asarray(poses)
    theta = math.atan2(np.sin(p[:, 2]).mean(), np.cos(p[:, 2]).mean())
    return Pose2D(x=float(p[:, 0].mean()), y=float(p[:, 1].mean()), theta=theta)
