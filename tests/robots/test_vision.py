"""Camera: lamps, QR landmarks (decodable, intrinsics/extrinsics consistent), doors, parameters."""
import base64
import math

import cv2
import numpy as np
import pytest

from ontology.robot import (CaptureImage, GetCameraInfo, GetTransform, LookAtPoint, SetCameraParam,
                            SetCameraParams)

from .conftest import api_at

LAMP = (0.4, 3.6, 1.4)
QR_S1 = (1.8, 3.95, 0.7)


def centre_mean(img, frac=0.15):
    h, w = img.shape[:2]
    dh, dw = int(h * frac), int(w * frac)
    return float(img[h // 2 - dh:h // 2 + dh, w // 2 - dw:w // 2 + dw].mean())


@pytest.mark.parametrize("kind,pose", [("nao", (1.6, 2.2, 120)), ("elektron", (2.2, 1.4, 120))])
async def test_lit_lamp_is_brighter_at_the_centre(small, kind, pose):
    api = api_at(small, kind, pose)
    api.robot.set_failure_modes(None)  # a fixed exposure (auto-exposure would darken the lit lamp's frame)
    await api.look_at_point(LookAtPoint(x=LAMP[0], y=LAMP[1], z=LAMP[2]))
    lit = await api.capture_array()
    await small.set_lamp("l1", False)
    unlit = await api.capture_array()
    assert centre_mean(lit) > centre_mean(unlit) + 60
    # low exposure (as the original light check used) keeps the lit lamp bright and darkens the rest
    await api.set_camera_params(SetCameraParams(exposure=0.2))
    dark_unlit = await api.capture_array()
    await small.set_lamp("l1", True)
    dark_lit = await api.capture_array()
    assert centre_mean(dark_lit, 0.05) > 150 > 60 > centre_mean(dark_unlit, 0.05)
    assert small.ground_truth().lamps == {"l1": True}


async def test_qr_landmark_decodes_and_matches_intrinsics_and_extrinsics(small):
    api = api_at(small, "nao", (1.8, 3.0, 90))
    await api.look_at_point(LookAtPoint(x=QR_S1[0], y=QR_S1[1], z=QR_S1[2]))
    reply = await api.capture_image(CaptureImage(camera="top", resolution="320x240"))
    img = cv2.imdecode(np.frombuffer(base64.b64decode(reply.data_b64), np.uint8), cv2.IMREAD_COLOR)
    assert (reply.width, reply.height) == (320, 240) and img.shape == (240, 320, 3)
    text, pts, _ = cv2.QRCodeDetector().detectAndDecode(img)
    assert text == "QR-S1"
    # project the landmark corners with K and the camera transform: they must land on the detected corners
    info = await api.get_camera_info(GetCameraInfo(camera="top", resolution="320x240"))
    K = np.array(info.K)
    T_base_cam = np.array((await api.get_transform(GetTransform(chain="top"))).matrix)
    x, y, th = small.ground_truth().robots["nao"]
    T_world_base = np.eye(4)
    T_world_base[:2, :2] = [[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]]
    T_world_base[:2, 3] = [x, y]
    T_cam_world = np.linalg.inv(T_world_base @ T_base_cam)
    lm = next(m for m in small.landmarks if m.id == "qr_s1")
    corners = np.array(lm.corners())
    pc = (T_cam_world @ np.c_[corners, np.ones(4)].T)[:3]
    uv = (K @ pc)[:2] / pc[2]
    proj = uv.T
    det = pts.reshape(-1, 2)
    # same order: TL, TR, BR, BL as seen (detector starts at the top-left finder pattern)
    assert np.abs(proj - det).max() < 2.0, (proj, det)
    # look_at_point centred the target
    centre = proj.mean(0)
    assert np.hypot(centre[0] - 159.5, centre[1] - 119.5) < 6


async def test_door_angle_changes_the_image(small):
    api = api_at(small, "elektron", (2.3, 1.45, 0))
    await api.look_at_point(LookAtPoint(x=3.5, y=1.45, z=0.0))
    closed = (await api.capture_array()).astype(int)
    await small.set_door("d1", 45)
    open45 = (await api.capture_array()).astype(int)
    assert small.ground_truth().doors["d1"] == 45
    assert np.abs(closed - open45).mean() > 4


async def test_door_angle_from_scenario_overrides(make_world):
    imgs = []
    for angle in (0, 45):
        w = make_world("small", seed=1, overrides={"doors": {"d1": angle}})
        api = api_at(w, "nao", (2.5, 1.45, 0))
        await api.look_at_point(LookAtPoint(x=3.5, y=1.45, z=0.0))
        imgs.append((await api.capture_array()).astype(int))
    assert np.abs(imgs[0] - imgs[1]).mean() > 4


async def test_camera_params_and_intrinsics(small):
    api = api_at(small, "elektron", (2.2, 1.4, 0))
    info = await api.get_camera_info(GetCameraInfo(resolution="640x480"))
    assert info.hfov_deg == pytest.approx(45.0)
    f = 320 / math.tan(math.radians(22.5))
    assert info.K[0][0] == pytest.approx(f) and info.K[1][1] == pytest.approx(f)
    assert info.D == [0.0] * 5
    base = await api.capture_array(resolution="QQVGA")
    assert base.shape == (120, 160, 3)
    await api.set_camera_param(SetCameraParam(name="brightness", value=0.2))
    brighter = await api.capture_array(resolution="QQVGA")
    assert brighter.mean() > base.mean() + 20
    # optical frame: z forward = robot x at zero head angles, x right = -robot y, y down = -robot z
    T = np.array((await api.get_transform(GetTransform(chain="camera"))).matrix)
    assert np.allclose(T[:3, 2], [1, 0, 0], atol=1e-6) and np.allclose(T[:3, 0], [0, -1, 0], atol=1e-6)
    assert T[2, 3] > 1.0  # camera on the mast
