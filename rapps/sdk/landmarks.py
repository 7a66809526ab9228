"""QR-landmark geometry shared by the SDK's localization on both sides (numpy only): where a
landmark's corners are in the world, their reprojection into a camera on the robot at a planar pose,
and how well the corners of some views fix that pose (the Gauss-Newton covariance of the fit).

The Cloud Agent fits the pose to the corners it measured (rapps/sdk/landmark_cloud.py); the task
predicts, before it captures a frame, which codes a head angle would show and how much they would
fix the pose (rapps/sdk/localize.py). Frames: code frame (centre, x right, y up on the printed code,
z out of its face); a landmark's yaw is its normal's, pointing into the room; camera optical frame
x right, y down, z forward; robot frame x forward, z up."""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from agents.services.transforms import invert, transform

if TYPE_CHECKING:
    from ontology.landmarks import Observation
    from ontology.services.common import CameraIntrinsics
    from ontology.services.home import LandmarkSpec

Pose = Sequence[float] | np.ndarray  # (x, y, theta)

PIXEL_NOISE = 0.5  # px, standard deviation of a refined corner (rendered codes, measured)


def planar_transform(x: float, y: float, theta: float) -> np.ndarray:
    """Robot base -> world of a planar pose."""
    c, s = math.cos(theta), math.sin(theta)
    return transform(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), [x, y, 0.0])


def corners_world(lm: LandmarkSpec) -> np.ndarray:
    """The 4 corners (TL, TR, BR, BL as the detector orders them) of a landmark (x, y, z, yaw,
    size_m) in the world, 4x3."""
    h = lm.size_m / 2.0
    n = np.array([math.cos(lm.yaw), math.sin(lm.yaw), 0.0])  # code +z
    right = np.cross([0.0, 0.0, 1.0], n)  # code +x = y (up) cross z
    up = np.array([0.0, 0.0, 1.0])
    c = np.array([lm.x, lm.y, lm.z])
    return np.array([c - h * right + h * up, c + h * right + h * up, c + h * right - h * up, c - h * right - h * up])


@dataclass
class View:
    """One code in one frame: its world corners, the camera's intrinsics and the camera's pose on the
    robot when the frame was (or would be) taken; `measured`: the corners found, pixels (4x2)."""

    corners: np.ndarray  # 4x3, world
    K: np.ndarray  # 3x3
    cam_from_robot: np.ndarray  # 4x4: robot base -> camera optical frame
    measured: np.ndarray | None = None


def intrinsics_matrix(camera: CameraIntrinsics) -> np.ndarray:
    return np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]], float)


def observed_views(observations: Iterable[Observation], landmarks: Mapping[str, LandmarkSpec]) -> list[View]:
    """The views of the observations that carry their corners and camera (ontology.landmarks.Observation)."""
    out = []
    for o in observations:
        if len(o.corners) != 4 or o.camera is None or len(o.camera_to_robot) != 4 or o.text not in landmarks:
            continue
        out.append(View(corners_world(landmarks[o.text]), intrinsics_matrix(o.camera),
                        invert(np.asarray(o.camera_to_robot, float)), np.asarray(o.corners, float)))
    return out


def project(q: Pose, view: View) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (4x2) of the view's corners from the robot pose q = (x, y, theta), and their depths."""
    T = view.cam_from_robot @ invert(planar_transform(*q))
    pc = (T[:3, :3] @ view.corners.T).T + T[:3, 3]
    z = np.maximum(pc[:, 2], 1e-3)
    K = view.K
    return np.stack([K[0, 0] * pc[:, 0] / z + K[0, 2], K[1, 1] * pc[:, 1] / z + K[1, 2]], 1), pc[:, 2]


def residuals(q: Pose, views: list[View]) -> np.ndarray:
    """Projected minus measured corners of every view (a view without measurements counts as 0)."""
    out = []
    for v in views:
        uv, _ = project(q, v)
        out.append((uv - (v.measured if v.measured is not None else uv)).ravel())
    return np.concatenate(out) if out else np.zeros(0)


def information(q: Pose, views: list[View]) -> np.ndarray:
    """J^T J / noise^2 of the views' corners at pose q: the information they give about (x, y, theta)."""
    q = np.asarray(q, float)
    info = np.zeros((3, 3))
    for v in views:
        u0 = project(q, v)[0].ravel()
        J = np.empty((len(u0), 3))
        for k, eps in enumerate((1e-5, 1e-5, 1e-6)):
            d = np.zeros(3)
            d[k] = eps
            J[:, k] = (project(q + d, v)[0].ravel() - u0) / eps
        info += J.T @ J
    return info / PIXEL_NOISE ** 2


def std_from_information(info: np.ndarray) -> tuple[float, float]:
    """(position std along the worst direction, heading std) of a pose known with `info`; inf when it
    leaves a direction unfixed."""
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return math.inf, math.inf
    if not np.all(np.isfinite(cov)) or np.linalg.cond(info) > 1e12:
        return math.inf, math.inf
    return (float(math.sqrt(max(np.linalg.eigvalsh(cov[:2, :2]).max(), 0.0))), float(math.sqrt(max(cov[2, 2], 0.0))))


def pose_std(q: Pose, views: list[View]) -> tuple[float, float]:
    """Standard deviations of a pose fitted to the views' corners (m along the worst direction, rad)
    from the corners' pixel noise: two codes close together or one far code leave the pose poorly fixed
    even when the residual is small."""
    return std_from_information(information(q, views))


def rigid_fit(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> tuple[float, float, float]:
    """(x, y, theta) of the transform b = R(theta) a + t minimizing the weighted squared error."""
    w = w / w.sum()
    ca, cb = (w[:, None] * a).sum(0), (w[:, None] * b).sum(0)
    A, B = a - ca, b - cb
    H = (w[:, None, None] * A[:, :, None] * B[:, None, :]).sum(0)
    theta = math.atan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
    R = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    t = cb - R @ ca
    return float(t[0]), float(t[1]), theta
