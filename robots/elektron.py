"""Elektron-like mobile base: differential drive (0.25 m/s), pan-tilt head with a narrow camera
(45 deg hfov), a 240 deg laser scanner at 0.26 m, two fixed Kinect depth cameras (paper 000, table 1:
the bottom one looks at the floor ahead, where the laser's plane misses low obstacles; the top one, on
the mast, ahead at table height), no speech synthesis."""
from __future__ import annotations

import math

from ontology.robot_types import robot_type

from .failure_modes import ElektronFailures, WheelSlip
from .spec import CameraSpec, DepthCameraSpec, RangeSpec, RobotSpec
from .urdf import JointDef, UrdfBuilder, box, cylinder

BODY = (0.2, 0.25, 0.4, 1)
DARK = (0.08, 0.08, 0.08, 1)
METAL = (0.6, 0.6, 0.62, 1)
TRACK_M = 0.35  # between the wheel sides: the URDF's wheels and the differential drive's model


def _urdf():
    b = UrdfBuilder("elektron")
    b.link("base_link", (box(0.40, 0.32, 0.16), (0, 0, 0.14), (0, 0, 0), BODY),
           (cylinder(0.07, 0.03), (0, TRACK_M / 2, 0.07), (math.pi / 2, 0, 0), DARK),
           (cylinder(0.07, 0.03), (0, -TRACK_M / 2, 0.07), (math.pi / 2, 0, 0), DARK),
           (cylinder(0.035, 0.05), (0.16, 0, 0.245), (0, 0, 0), DARK),
           (box(0.04, 0.04, 0.78), (-0.12, 0, 0.61), (0, 0, 0), METAL))
    b.link("laser")
    b.joint(JointDef("laser_fixed", "fixed", "base_link", "laser", xyz=(0.16, 0, 0.26)))
    b.link("pan", (cylinder(0.03, 0.04), (0, 0, 0.02), (0, 0, 0), DARK))
    b.joint(JointDef("HeadPan", "revolute", "base_link", "pan", xyz=(-0.12, 0, 1.0), lower=-2.8, upper=2.8, velocity=3.0))
    b.link("tilt", (box(0.05, 0.12, 0.05), (0.02, 0, 0), (0, 0, 0), DARK),
           (cylinder(0.018, 0.01), (0.05, 0, 0), (0, math.pi / 2, 0), METAL))
    b.joint(JointDef("HeadTilt", "revolute", "pan", "tilt", xyz=(0, 0, 0.07), axis=(0, 1, 0), lower=-0.6, upper=1.1, velocity=3.0))
    b.link("camera")
    b.joint(JointDef("camera_fixed", "fixed", "tilt", "camera", xyz=(0.056, 0, 0)))
    return b.write(), b.limits()


POSTURES = {name: {"HeadPan": 0.0, "HeadTilt": 0.0} for name in ("Zero", "Stand", "StandInit")}

SPEC = RobotSpec(
    kind="elektron", build_urdf=_urdf, radius=robot_type("elektron").body_radius_m, collision_height=0.45, holonomic=False,
    max_vx=0.25, max_vy=0.0, max_wz=1.0,
    cameras=[CameraSpec("head", "camera", 45.0)],
    head_yaw="HeadPan", head_pitch="HeadTilt", look_camera="head", joint_speed=1.5,
    postures=POSTURES, rest_posture="Zero",
    laser=RangeSpec("laser", "laser", -math.radians(120), math.radians(120), 241, 0.02, 5.6),
    depth_cameras=(DepthCameraSpec("kinect_bottom", "base_link", (0.14, 0.0, 0.42), pitch_deg=25.0),
                   DepthCameraSpec("kinect_top", "base_link", (-0.08, 0.0, 0.95), pitch_deg=10.0)),
    speech=False, failures=ElektronFailures(wheels=WheelSlip(track_m=TRACK_M)),
)
