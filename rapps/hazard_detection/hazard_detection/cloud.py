"""Cloud Agent part: QR-marker global localization (paper 001 fig. 6), with the Platform's shared math."""
import asyncio

import cv2
import numpy as np

from agents.services import localization as L
from agents.services.images import decode_image
from rapps.sdk import CloudService

from .models import ONTOLOGY, Localization, Localize


def localize(req: Localize) -> Localization:
    img = decode_image(req.image_b64)
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    K, dist = L.camera_matrix(req.camera)
    T_robot_cam = np.asarray(req.camera_to_robot, float)
    poses, used, dists = [], [], []
    for text, corners in L.detect_qr(img):
        lm = req.landmarks.get(text)
        if lm is None:
            continue
        T_cam_code = L.code_pose(L.refine_corners(gray, corners), lm.size_m, K, dist)
        d = float(np.linalg.norm(T_cam_code[:3, 3]))
        if d > req.max_distance_m:
            continue
        poses.append(L.planar(L.robot_pose_from_code(T_cam_code, T_robot_cam, lm)))
        used.append(text)
        dists.append(d)
    if not poses:
        return Localization(found=False)
    p = np.asarray(poses)
    w = 1.0 / np.asarray(dists) ** 2  # nearer codes are more accurate
    theta = float(np.arctan2((w * np.sin(p[:, 2])).sum(), (w * np.cos(p[:, 2])).sum()))
    pose = dict(x=float(np.average(p[:, 0], weights=w)), y=float(np.average(p[:, 1], weights=w)), theta=theta)
    return Localization(found=True, pose=pose, markers=used, distance_m=min(dists))


class LocalizationCloud(CloudService):
    ontology = ONTOLOGY

    async def localize(self, req: Localize) -> Localization:
        return await asyncio.to_thread(localize, req)
