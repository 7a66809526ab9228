import asyncio

import numpy as np
import pytest

from agents.services import hazard
from agents.services.errors import ServiceError
from agents.services.images import encode_image
from ontology.services.common import CameraIntrinsics
from ontology.services.hazard import DoorCheck, DoorGeometry, LightCheck

ANGLES = (0, 30, 60, 90)


def test_light_level_synthetic(ctx):
    dark = np.full((240, 320), 150, np.uint8)
    lit = dark.copy()
    lit[90:150, 130:190] = 255
    assert hazard.light_check(LightCheck(image_b64=encode_image(dark)), ctx).light_level == 0
    out = hazard.light_check(LightCheck(image_b64=encode_image(lit)), ctx)
    assert out.lamp_on and out.light_level > 60
    # resolution independent
    big = np.kron(lit, np.ones((3, 3), np.uint8))
    assert abs(hazard.light_level(big) - out.light_level) <= 2


def test_bad_image(ctx):
    with pytest.raises(ServiceError):
        hazard.door_check(DoorCheck(image_b64="!!notbase64"), ctx)


@pytest.fixture(scope="module")
def renders():
    """Elektron in the 'small' house looking at door d1 (angles 0..90) and at lamp l1 (on / off)."""
    robots = pytest.importorskip("robots")
    from ontology.robot import CaptureImage, GetCameraInfo, GetTransform, LookAtPoint

    async def shoot():
        out = {}
        for ang in ANGLES:
            world = robots.World.from_file("small", seed=1, overrides={"doors": {"d1": ang}, "lamps": {"l1": ang >= 60}})
            try:
                api = robots.RobotAPI(world.add_robot("elektron", pose=(2.5, 1.2, 0.0)))
                await api.look_at_point(LookAtPoint(x=3.5, y=1.3, z=0.0))
                door = await api.capture_image(CaptureImage(resolution="640x480"))
                info = await api.get_camera_info(GetCameraInfo(resolution="640x480"))
                tf = await api.get_transform(GetTransform(chain="camera", space="global"))
                await api.look_at_point(LookAtPoint(x=0.4, y=3.6, z=1.4))
                lamp = await api.capture_image(CaptureImage(resolution="320x240"))
                truth = world.ground_truth()
            finally:
                world.close()
            out[ang] = dict(door=door.data_b64, lamp=lamp.data_b64, K=np.asarray(info.K), T=tf.matrix,
                            truth_door=truth.doors["d1"], truth_lamp=truth.lamps["l1"])
        return out

    return asyncio.run(shoot())


@pytest.mark.parametrize("ang", ANGLES)
def test_door_angle_on_pybullet_render(ctx, renders, ang):
    r = renders[ang]
    K = r["K"]
    geo = DoorGeometry(camera=CameraIntrinsics(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2]),
                       camera_to_world=r["T"], hinge=[3.5, 1.0], closed_yaw_deg=90, width_m=0.9)
    out = hazard.door_check(DoorCheck(image_b64=r["door"], geometry=geo), ctx)
    assert out.method == "geometry"
    assert abs(out.door_angle - r["truth_door"]) <= 5.0


@pytest.mark.parametrize("ang", ANGLES)
def test_lamp_state_on_pybullet_render(ctx, renders, ang):
    r = renders[ang]
    assert hazard.light_check(LightCheck(image_b64=r["lamp"]), ctx).lamp_on == r["truth_lamp"]
