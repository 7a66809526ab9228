"""NAO-like humanoid: holonomic walking abstracted as a moving base, real head/arm/leg joints,
two head cameras (top 61 deg hfov, bottom pitched down 39.7 deg), two chest sonars, speech."""
from __future__ import annotations

import math

from ontology.robot_types import robot_type

from .contact_sensors import BumperSpec
from .failure_modes import NaoFailures
from .mic_array import NAO_MICS
from .spec import CameraSpec, RangeSpec, RobotSpec
from .urdf import JointDef, UrdfBuilder, box, cylinder, sphere

WHITE = (0.93, 0.93, 0.95, 1)
GREY = (0.45, 0.47, 0.5, 1)
ORANGE = (0.95, 0.55, 0.15, 1)
DARK = (0.1, 0.1, 0.12, 1)

THIGH, SHIN, FOOT_H = 0.100, 0.1029, 0.045
NECK_Z = 0.2115
HEAD_YAW_LIM = 2.0857
HEAD_PITCH_LIM = (-0.6720, 0.5149)


def _urdf():
    b = UrdfBuilder("nao")
    b.link("base_footprint")
    b.link("torso", (box(0.075, 0.13, 0.17), (0, 0, 0.11), (0, 0, 0), WHITE),
           (box(0.06, 0.1, 0.04), (0, 0, 0.025), (0, 0, 0), GREY),
           (box(0.01, 0.05, 0.05), (0.04, 0, 0.13), (0, 0, 0), ORANGE))
    b.joint(JointDef("BaseLift", "prismatic", "base_footprint", "torso", axis=(0, 0, 1), lower=0.0, upper=0.4))
    b.link("Neck", (cylinder(0.018, 0.03), (0, 0, -0.01), (0, 0, 0), GREY))
    b.joint(JointDef("HeadYaw", "revolute", "torso", "Neck", xyz=(0, 0, NECK_Z), lower=-HEAD_YAW_LIM, upper=HEAD_YAW_LIM, velocity=8.0))
    b.link("Head", (sphere(0.055), (-0.005, 0, 0.05), (0, 0, 0), WHITE),
           (box(0.012, 0.09, 0.02), (0.05, 0, 0.045), (0, 0, 0), DARK))
    b.joint(JointDef("HeadPitch", "revolute", "Neck", "Head", axis=(0, 1, 0), lower=HEAD_PITCH_LIM[0], upper=HEAD_PITCH_LIM[1], velocity=7.0))
    b.link("CameraTop")
    b.joint(JointDef("CameraTop_fixed", "fixed", "Head", "CameraTop", xyz=(0.0639, 0, 0.0679)))
    b.link("CameraBottom")
    b.joint(JointDef("CameraBottom_fixed", "fixed", "Head", "CameraBottom", xyz=(0.0588, 0, -0.0233), rpy=(0, 0.6929, 0)))
    for side, s in (("L", 1), ("R", -1)):
        b.link(f"{side}Shoulder", (sphere(0.025), (0, 0, 0), (0, 0, 0), WHITE))
        b.joint(JointDef(f"{side}ShoulderPitch", "revolute", "torso", f"{side}Shoulder", xyz=(0, s * 0.098, 0.185),
                         axis=(0, 1, 0), lower=-2.0857, upper=2.0857))
        b.link(f"{side}Bicep", (cylinder(0.02, 0.105), (0.0525, 0, 0), (0, math.pi / 2, 0), WHITE))
        lo, hi = (-0.3142, 1.3265) if s > 0 else (-1.3265, 0.3142)
        b.joint(JointDef(f"{side}ShoulderRoll", "revolute", f"{side}Shoulder", f"{side}Bicep", axis=(0, 0, 1), lower=lo, upper=hi))
        b.link(f"{side}Forearm", (cylinder(0.018, 0.11), (0.055, 0, 0), (0, math.pi / 2, 0), GREY))
        lo, hi = (-1.5446, -0.0349) if s > 0 else (0.0349, 1.5446)
        b.joint(JointDef(f"{side}ElbowRoll", "revolute", f"{side}Bicep", f"{side}Forearm", xyz=(0.105, 0, 0),
                         axis=(0, 0, 1), lower=lo, upper=hi))
        b.link(f"{side}Thigh", (cylinder(0.028, THIGH), (0, 0, -THIGH / 2), (0, 0, 0), WHITE))
        b.joint(JointDef(f"{side}HipPitch", "revolute", "torso", f"{side}Thigh", xyz=(0, s * 0.05, 0),
                         axis=(0, 1, 0), lower=-1.7736, upper=0.4845))
        b.link(f"{side}Tibia", (cylinder(0.025, SHIN), (0, 0, -SHIN / 2), (0, 0, 0), WHITE))
        b.joint(JointDef(f"{side}KneePitch", "revolute", f"{side}Thigh", f"{side}Tibia", xyz=(0, 0, -THIGH),
                         axis=(0, 1, 0), lower=-0.0923, upper=2.1125))
        b.link(f"{side}Foot", (box(0.16, 0.08, 0.03), (0.02, 0, -FOOT_H + 0.015), (0, 0, 0), GREY))
        b.joint(JointDef(f"{side}AnklePitch", "revolute", f"{side}Tibia", f"{side}Foot", xyz=(0, 0, -SHIN),
                         axis=(0, 1, 0), lower=-1.1895, upper=0.9227))
    for side, s in (("Left", 1), ("Right", -1)):
        b.link(f"Sonar{side}")
        b.joint(JointDef(f"Sonar{side}_fixed", "fixed", "torso", f"Sonar{side}", xyz=(0.045, s * 0.04, 0.08),
                         rpy=(0, 0, s * math.radians(25))))
    return b.write(), b.limits()


def lift_height(q: dict[str, float]) -> float:
    """Hip height that keeps the lower foot on the floor for the given leg angles."""
    heights = []
    for side in "LR":
        h, k, a = q.get(f"{side}HipPitch", 0.0), q.get(f"{side}KneePitch", 0.0), q.get(f"{side}AnklePitch", 0.0)
        heights.append(THIGH * math.cos(h) + SHIN * math.cos(h + k) + FOOT_H * math.cos(h + k + a))
    return max(max(heights), 0.06)


def _arms(pitch: float, roll: float, elbow: float) -> dict[str, float]:
    return {"LShoulderPitch": pitch, "RShoulderPitch": pitch, "LShoulderRoll": roll, "RShoulderRoll": -roll,
            "LElbowRoll": -elbow, "RElbowRoll": elbow}


def _legs(hip: float, knee: float, ankle: float) -> dict[str, float]:
    return {f"{s}{j}": v for s in "LR" for j, v in (("HipPitch", hip), ("KneePitch", knee), ("AnklePitch", ankle))}


POSTURES = {
    "Zero": {"HeadYaw": 0.0, "HeadPitch": 0.0, **_arms(0.0, 0.0, 0.0349), **_legs(0.0, 0.0, 0.0)},
    "Stand": {"HeadYaw": 0.0, "HeadPitch": 0.0, **_arms(1.4, 0.25, 0.9), **_legs(-0.1, 0.2, -0.1)},
    "StandInit": {"HeadYaw": 0.0, "HeadPitch": 0.0, **_arms(1.4, 0.25, 0.9), **_legs(-0.45, 0.7, -0.35)},
    "StandZero": {"HeadYaw": 0.0, "HeadPitch": 0.0, **_arms(1.4, 0.0, 0.0349), **_legs(0.0, 0.0, 0.0)},
    "Crouch": {"HeadYaw": 0.0, "HeadPitch": 0.0, **_arms(1.5, 0.1, 0.5), **_legs(-0.9, 2.1, -1.18)},
    "Sit": {"HeadYaw": 0.0, "HeadPitch": 0.0, **_arms(0.9, 0.2, 0.3), **_legs(-1.5, 0.0, 0.0)},
}


SPEC = RobotSpec(
    kind="nao", build_urdf=_urdf, radius=robot_type("nao").body_radius_m, collision_height=0.45, holonomic=True,
    max_vx=0.12, max_vy=0.10, max_wz=0.6,
    cameras=[CameraSpec("top", "CameraTop", 60.97), CameraSpec("bottom", "CameraBottom", 60.97)],
    head_yaw="HeadYaw", head_pitch="HeadPitch", look_camera="top", joint_speed=2.0,
    postures=POSTURES, rest_posture="Crouch",
    sonars=[RangeSpec("sonar_left", "SonarLeft", -0.26, 0.26, 5, 0.25, 2.55),
            RangeSpec("sonar_right", "SonarRight", -0.26, 0.26, 5, 0.25, 2.55)],
    bumpers=(BumperSpec("bumper_left", "LFoot"), BumperSpec("bumper_right", "RFoot")),
    touch_sensors=("head_front", "head_middle", "head_rear", "hand_left", "hand_right"),
    speech=True, microphones=NAO_MICS, lift_joint="BaseLift", lift_height=lift_height, hidden_joints=("BaseLift",),
    failures=NaoFailures(),
)
