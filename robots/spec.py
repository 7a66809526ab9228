"""Static description of a robot model: kinematics limits, cameras, sensors, postures."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable


@dataclass(frozen=True)
class CameraSpec:
    name: str
    link: str  # URDF link whose frame is x forward, y left, z up at the optical centre
    hfov_deg: float
    near: float = 0.02
    far: float = 40.0


@dataclass(frozen=True)
class RangeSpec:
    """A ray fan mounted on `link` (x forward): sonar cone or laser scan."""

    name: str
    link: str
    angle_min: float
    angle_max: float
    rays: int
    range_min: float
    range_max: float


@dataclass(frozen=True)
class DepthCameraSpec:
    """A depth camera (a Kinect) fixed on `link`, `xyz` (m) ahead/left/up of it, pitched `pitch_deg` down;
    its noise model is robots/depth_camera.py's."""

    name: str
    link: str
    xyz: tuple[float, float, float]
    pitch_deg: float
    hfov_deg: float = 57.0  # Kinect v1: 57 x 43 deg
    range_min: float = 0.5  # m: nearer, no return
    range_max: float = 4.5
    near: float = 0.05  # the render's clipping planes
    far: float = 12.0


@dataclass
class RobotSpec:
    """A body (robots/nao.py, robots/elektron.py) of a robot type of ontology/robot_types.py."""

    kind: str
    build_urdf: Callable[[], "tuple[Path, dict[str, tuple[float, float]]]"]
    radius: float  # collision cylinder: the type's body_radius_m
    collision_height: float
    holonomic: bool
    max_vx: float
    max_vy: float
    max_wz: float
    cameras: list[CameraSpec]
    head_yaw: str
    head_pitch: str
    look_camera: str
    joint_speed: float  # rad/s at speed fraction 1
    postures: dict[str, dict[str, float]]
    rest_posture: str
    sonars: list[RangeSpec] = field(default_factory=list)
    laser: RangeSpec | None = None
    speech: bool = False
    # microphones of an array, in the robot's frame (forward, left, up from the listening point); () for one
    microphones: tuple[tuple[float, float, float], ...] = ()
    lift_joint: str | None = None  # virtual prismatic joint keeping the feet on the floor
    lift_height: Callable[[dict[str, float]], float] | None = None
    hidden_joints: tuple[str, ...] = ()
    bumpers: tuple[Any, ...] = ()  # robots.contact_sensors.BumperSpec: a foot's toe
    touch_sensors: tuple[str, ...] = ()  # touch sensors a scenario presses (World.touch)
    depth_cameras: tuple[DepthCameraSpec, ...] = ()
    # how it fails like a real one (robots/failure_modes.py NaoFailures, ElektronFailures); None: ideal
    failures: Any = None
