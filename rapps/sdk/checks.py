"""The hazard checks as one call each, from where the robot stands (docs/sdk.md, "Checking doors and
lamps"): look, take the picture, ask the Platform.

    reply = await check_door(self, door)     # door: a DoorwaySpec or HazardSpec of home_get_info
    reply = await check_light(self, lamp)    # lamp: a lamp's HazardSpec, or the point (x, y, z) to look at

`check_door` with the "geometry" method builds the check's geometry (`door_geometry`) from the camera
the picture was taken with (get_camera_info's intrinsics, get_transform's camera pose in the global
frame, which goes through the robot's pose estimate: localize first) and the door's shape in the home
description. `check_light` takes the picture at a low exposure, so that only light sources stay
bright, and restores the camera's parameters whatever happens.
"""
from __future__ import annotations

import math
from typing import Protocol, Sequence

from ontology.robot import CameraInfo, Transform
from ontology.services.common import CameraIntrinsics
from ontology.services.hazard import DoorAngle, DoorGeometry, DoorMethod, LightLevel
from ontology.services.home import DoorShape, DoorwaySpec, HazardSpec

from .calls import PlatformCalls, RobotCalls

Matrix4 = list[list[float]]
Door = DoorwaySpec | HazardSpec | DoorShape


class TaskCalls(Protocol):
    """What the checks use of a Task (rapps.sdk.Task): its robot and Platform calls."""

    @property
    def robot(self) -> RobotCalls: ...

    @property
    def platform(self) -> PlatformCalls: ...


LIGHT_EXPOSURE = 0.2  # the hazard RApp's: a lit lamp's shade stays bright, a lit wall does not


def door_shape(door: Door) -> DoorShape:
    shape = door if isinstance(door, DoorShape) else door.door
    if shape is None:
        raise ValueError(f"{getattr(door, 'id', door)!r} is not a door (a lamp's HazardSpec?)")
    return shape


def intrinsics(info: CameraInfo) -> CameraIntrinsics:
    """The pinhole intrinsics of get_camera_info's K (at the resolution it was asked for)."""
    K = info.K
    return CameraIntrinsics(fx=K[0][0], fy=K[1][1], cx=K[0][2], cy=K[1][2], dist=list(info.D))


def door_geometry(info: CameraInfo, camera_to_world: Transform | Matrix4, door: Door) -> DoorGeometry:
    """What the door check's "geometry" method needs: the camera's intrinsics (CameraInfo at the
    picture's resolution), its optical frame in the world (get_transform(chain="camera",
    space="global"), or a 4x4 matrix) and the door's hinge, closed direction and width."""
    matrix = camera_to_world.matrix if isinstance(camera_to_world, Transform) else camera_to_world
    if isinstance(camera_to_world, Transform) and camera_to_world.space != "global":
        raise ValueError("the camera's pose must be in the global frame: get_transform(space=\"global\")")
    shape = door_shape(door)
    return DoorGeometry(camera=intrinsics(info), camera_to_world=matrix, hinge=list(shape.hinge),
                        closed_yaw_deg=shape.closed_yaw_deg, width_m=shape.width_m)


def door_look_point(door: Door, method: DoorMethod, at: tuple[float, float] | None = None) -> list[float]:
    """Where the camera looks for a door check. The image method needs the hinge (where the door
    frame meets the floor: one floor line in each half of the image); the geometry method looks at the
    check's own point: a HazardSpec's `look_at`, or that of the doorway's check pose nearest to `at`
    (the robot's position), else the hinge."""
    shape = door_shape(door)
    hinge = [shape.hinge[0], shape.hinge[1], 0.0]
    if method == "image":
        return hinge
    if isinstance(door, HazardSpec):
        return list(door.look_at)
    if isinstance(door, DoorwaySpec) and door.checks:
        if at is None:
            return list(door.checks[0].look_at)
        near = min(door.checks, key=lambda c: math.hypot(c.stand.x - at[0], c.stand.y - at[1]))
        return list(near.look_at)
    return hinge


async def check_door(task: TaskCalls, door: Door, *, method: DoorMethod = "geometry", resolution: str = "640x480",
                     look_at: Sequence[float] | None = None) -> DoorAngle:
    """Check a door from where the robot stands: turn the camera to it, take a picture and ask the
    Platform's hazard_detection_door_check. `task`: the RApp's Task (its `robot` and `platform`);
    `look_at`: a point (x, y, z) to look at instead of door_look_point's. The answer's `door_angle`
    is in degrees (0 closed); its `confidence` says how far to trust it (look again from the doorway's
    other check pose when it is low). Needs the manifest's `vision` and `navigation` robot-API groups
    and the service `hazard_detection_door_check`."""
    robot = task.robot
    if look_at is None:
        at = None
        if method == "geometry" and isinstance(door, DoorwaySpec) and len(door.checks) > 1:
            pose = await robot.get_global_pose()
            at = (pose.x, pose.y)
        look_at = door_look_point(door, method, at)
    x, y, z = look_at
    await robot.look_at_point(x=x, y=y, z=z)
    image = await robot.capture_image(resolution=resolution)
    geometry = None
    if method == "geometry":
        info = await robot.get_camera_info(resolution=resolution)
        camera_pose = await robot.get_transform(chain="camera", space="global")
        geometry = door_geometry(info, camera_pose, door)
    return await task.platform.hazard_detection_door_check(image_b64=image.data_b64, method=method,
                                                           geometry=geometry)


async def check_light(task: TaskCalls, lamp: HazardSpec | Sequence[float], *, exposure: float = LIGHT_EXPOSURE,
                      on_threshold: int = 30, resolution: str = "320x240") -> LightLevel:
    """Check a lamp from where the robot stands: turn the camera to it (a lamp's HazardSpec's
    `look_at`, or a point x, y, z), take a picture at a low `exposure` (the camera's parameters are
    restored afterwards, whatever happens) and ask the Platform's hazard_detection_light_check. The
    answer's `lamp_on` is its `light_level` (0..100) against `on_threshold`. Needs the manifest's
    `vision` and `navigation` robot-API groups and the service `hazard_detection_light_check`."""
    robot = task.robot
    x, y, z = lamp.look_at if isinstance(lamp, HazardSpec) else lamp
    saved = await robot.set_camera_params()  # no field given: changes nothing, answers the current ones
    try:
        await robot.set_camera_params(exposure=float(exposure), auto_exposure=False)
        await robot.look_at_point(x=x, y=y, z=z)
        image = await robot.capture_image(resolution=resolution)
    finally:
        await robot.set_camera_params(exposure=saved.exposure, auto_exposure=saved.auto_exposure)
    return await task.platform.hazard_detection_light_check(image_b64=image.data_b64, on_threshold=on_threshold)
