"""Synthetic camera images for tests and demos: a planar texture seen by a pinhole camera."""
from __future__ import annotations

import cv2
import numpy as np


def qr_texture(text: str, module_px: int = 20) -> tuple[np.ndarray, int]:
    """QR image (with its quiet zone) and the quiet-zone width in modules."""
    q = cv2.QRCodeEncoder.create().encode(text)
    ys, _ = np.where(q == 0)
    border = int(ys.min())
    return cv2.resize(q, None, fx=module_px, fy=module_px, interpolation=cv2.INTER_NEAREST), border


def render_plane(texture: np.ndarray, corners_3d: np.ndarray, K: np.ndarray, size=(1280, 960),
                 background: int = 110, T_cam_obj: np.ndarray | None = None) -> np.ndarray:
    """Project the texture whose 4 corners (TL, TR, BR, BL) are corners_3d in the object frame
    (camera frame if T_cam_obj is None) into a gray image of the given (w, h)."""
    P = corners_3d if T_cam_obj is None else (T_cam_obj[:3, :3] @ corners_3d.T).T + T_cam_obj[:3, 3]
    uv = (K @ P.T).T
    uv = (uv[:, :2] / uv[:, 2:]).astype(np.float32)
    h, w = texture.shape[:2]
    src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    H = cv2.getPerspectiveTransform(src, uv)
    img = np.full((size[1], size[0]), background, np.uint8)
    warped = cv2.warpPerspective(texture, H, size, flags=cv2.INTER_AREA)
    mask = cv2.warpPerspective(np.full(texture.shape[:2], 255, np.uint8), H, size, flags=cv2.INTER_AREA)
    alpha = mask.astype(np.float32) / 255.0
    return (alpha * warped + (1 - alpha) * img).astype(np.uint8)


def render_qr(text: str, code_size: float, T_cam_code: np.ndarray, K: np.ndarray, size=(1280, 960)) -> np.ndarray:
    """A QR code of side code_size (m, dark modules only) at pose T_cam_code, on a gray wall."""
    tex, border = qr_texture(text)
    modules = tex.shape[0] // 20 - 2 * border
    half = code_size / 2 * (modules + 2 * border) / modules  # texture incl. quiet zone
    corners = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]], float)
    return render_plane(tex, corners, K, size, T_cam_obj=T_cam_code)
