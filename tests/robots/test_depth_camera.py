"""The Elektron's depth cameras (robots/depth_camera.py): metres from the depth buffer, a Kinect v1's noise
(grows with range, quantized disparity, missing returns far away and on oblique surfaces), the same image
from a render process as inline, and the robot API's capture_depth."""
import base64
import math

import numpy as np
import pytest

from ontology.robot import CaptureDepth, GetTransform
from robots import InvalidArgument, UnsupportedOperation
from robots.depth_camera import axial_sigma, intrinsics, kinect
from robots.depth_png import decode_depth

from .conftest import api_at

K = intrinsics(57.0, 160, 120)


def _plane(z0: float, tilt: float = 0.0) -> np.ndarray:
    """True depth of a plane z0 ahead, turned `tilt` rad about the vertical axis (incidence = tilt at the centre)."""
    u = np.arange(160) - K[0, 2]
    x = u / K[0, 0]  # ray slope
    z = z0 / (1 + x * math.tan(tilt))
    return np.tile(z, (120, 1)).astype(np.float32)


def test_noise_grows_with_range_and_is_quantized():
    rng = np.random.default_rng()  # drawn at run time: the model holds at any seed
    near, far = kinect(_plane(1.0), K, 0.5, 4.5, rng), kinect(_plane(4.0), K, 0.5, 4.5, rng)
    assert (near > 0).all() and (far > 0).all()
    e_near, e_far = np.std(near - 1.0), np.std(far - 4.0)
    assert 0.001 < e_near < 0.006 and 0.015 < e_far < 0.06 and e_far > 5 * e_near
    assert abs(np.mean(far) - 4.0) < 0.01  # unbiased
    steps = np.unique(np.round(far, 4))
    assert 2 <= len(steps) < 20 and np.min(np.diff(steps)) > 0.03  # disparity steps: ~4.9 cm at 4 m
    assert math.isclose(float(axial_sigma(np.array(3.0), np.array(0.0))), 0.0012 + 0.0019 * 2.6 ** 2)


def test_missing_returns_out_of_range_and_on_oblique_surfaces():
    rng = np.random.default_rng()
    assert (kinect(_plane(5.0), K, 0.5, 4.5, rng) == 0).all() and (kinect(_plane(0.4), K, 0.5, 4.5, rng) == 0).all()
    frontal = kinect(_plane(2.0), K, 0.5, 4.5, rng)
    grazing = kinect(_plane(2.0, math.radians(84)), K, 0.5, 4.5, rng)  # 84 deg at the centre
    assert (frontal > 0).mean() == 1.0 and (grazing[:, 70:90] > 0).mean() < 0.05
    ideal = kinect(_plane(2.0, math.radians(84)), K, 0.5, 4.5, None)  # no failure modes: exact where in range
    z = _plane(2.0, math.radians(84))
    inside = (z >= 0.5) & (z <= 4.5)
    assert np.array_equal(ideal[inside], z[inside]) and (ideal[~inside] == 0).all()


async def test_captured_depth_matches_the_wall_and_its_noise(small):
    el = api_at(small, "elektron", (1.45, 2.4, 0))  # the inner wall's face at x = 3.45, 2.1 m ahead of the top Kinect
    api = el

    async def wall_x(noisy: bool) -> np.ndarray:
        await small.run(el.robot.set_failure_modes, el.robot.spec.failures if noisy else None)
        img = await api.capture_depth(CaptureDepth(camera="kinect_top", resolution="160x120"))
        z = decode_depth(base64.b64decode(img.data_b64))
        Kc, T = np.asarray(img.K), np.asarray(img.camera_to_robot)
        v, u = np.nonzero(z > 0)
        d = z[v, u]
        pts = T[:3, :3] @ np.stack([(u - Kc[0, 2]) / Kc[0, 0] * d, (v - Kc[1, 2]) / Kc[1, 1] * d, d]) + T[:3, 3:4]
        wall = (pts[2] > 0.3) & (pts[2] < 1.5) & (pts[1] > -0.3) & (pts[1] < 1.3)  # not the door (y 1.0-1.9)
        return pts[0][wall] + 1.45  # robot at x = 1.45, heading +x

    exact = await wall_x(False)
    assert len(exact) > 5000 and np.max(np.abs(exact - 3.45)) < 0.003
    noisy = await wall_x(True)
    assert 0.004 < np.std(noisy - 3.45) < 0.04 and abs(np.median(noisy) - 3.45) < 0.02
    top = await api.get_transform(GetTransform(chain="kinect_top"))
    assert abs(top.matrix[2][3] - 0.95) < 1e-6  # mounted on the mast


async def test_a_render_process_gives_the_inline_image(make_world):
    images = []
    for render in ("inline", "process"):
        world = make_world("small", seed=3, render=render)
        el = api_at(world, "elektron", (1.0, 1.9, 20))
        images.append(decode_depth(base64.b64decode(
            (await el.capture_depth(CaptureDepth(resolution="80x60"))).data_b64)))
    assert images[0].shape == (60, 80) and (images[0] > 0).mean() > 0.5
    assert np.array_equal(images[0], images[1])  # the same seeded noise, computed in the render process


async def test_capture_depth_refuses_what_it_cannot_do(small):
    nao = api_at(small, "nao", (1.0, 2.4, 0))
    with pytest.raises(UnsupportedOperation, match="no depth camera"):
        await nao.capture_depth(CaptureDepth())
    el = api_at(small, "elektron", (2.2, 0.5, 90))
    with pytest.raises(InvalidArgument, match="320x240"):
        await el.capture_depth(CaptureDepth(resolution="640x480"))
    with pytest.raises(InvalidArgument, match="unknown depth camera"):
        await el.capture_depth(CaptureDepth(camera="head"))
    img = await el.capture_depth(CaptureDepth())
    assert (img.camera, img.width, img.height, img.encoding) == ("kinect_bottom", 320, 240, "png16mm")
    assert {"depth", "laser"} <= el.capabilities() and "depth" not in nao.capabilities()
