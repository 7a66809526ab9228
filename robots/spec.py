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
    # how it fails like a real one (robots/failure_modes.py NaoFailures, ElektronFailures); None: ideal
    failures: Any = None
