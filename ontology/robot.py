"""Robot-API message models (ontology "robot"): one request model per RobotAPI method.

The Core dispatches generically: ``await getattr(api, req.action_name)(req)`` returns the reply model
named by ``type(req).reply_model``. Units: metres, radians, seconds (simulation time). Poses are in the
GLOBAL (map) frame unless stated otherwise; ``move_to`` is relative to the robot.
Camera optical frame convention: x right, y down, z forward (OpenCV).
"""
from __future__ import annotations

from pydantic import Field

from .registry import Action, Content, Done, action, actions
from .services.common import Pose2D  # one Pose2D for robot and Platform messages

__all__ = ["Pose2D"]  # re-exported: robot messages use the Platform's pose model

ONTOLOGY = "robot"


# ---------------------------------------------------------------- reply / shared contents
class WordSpotted(Content):
    """First matching word heard, or word=None when the timeout expired."""

    word: str | None = None
    text: str | None = None


class Image(Content):
    camera: str
    width: int
    height: int
    encoding: str = "png"
    data_b64: str
    stamp: float = 0.0


class CameraParams(Content):
    """Post-render image adjustments. out = clip(((radiance*exposure*gain) - .5)*contrast + .5 + brightness).
    Lit lamps have radiance > 1, so a low-exposure image shows mostly the light sources."""

    brightness: float = 0.0
    contrast: float = 1.0
    gain: float = 1.0
    exposure: float = 1.0
    auto_exposure: bool = False


class CameraInfo(Content):
    """Pinhole intrinsics exactly matching the render (pixel centres at integer coordinates)."""

    camera: str
    width: int
    height: int
    K: list[list[float]]
    D: list[float] = Field(default_factory=lambda: [0.0] * 5)
    P: list[list[float]]
    hfov_deg: float
    vfov_deg: float
    frame: str = "optical: x right, y down, z forward"


class Transform(Content):
    chain: str
    space: str
    matrix: list[list[float]]


class JointAngles(Content):
    joints: list[str]
    angles: list[float]


class SonarReading(Content):
    left: float
    right: float
    range_min: float
    range_max: float


class LaserScan(Content):
    angle_min: float
    angle_max: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: list[float]


# ---------------------------------------------------------------- communication
@action("say", ontology=ONTOLOGY, reply=Done, group="communication")
class Say(Action):
    text: str
    language: str = "en"


@action("word_spotting", ontology=ONTOLOGY, reply=WordSpotted, group="communication")
class WordSpotting(Action):
    words: list[str]
    timeout: float = 10.0  # wall-clock seconds (speech comes from a person or a scenario script)


# ---------------------------------------------------------------- vision
@action("capture_image", ontology=ONTOLOGY, reply=Image, group="vision")
class CaptureImage(Action):
    camera: str = ""  # "" = the robot's main camera
    resolution: str = "320x240"  # "WxH" or QQVGA/QVGA/VGA


@action("set_camera_param", ontology=ONTOLOGY, reply=CameraParams, group="vision")
class SetCameraParam(Action):
    camera: str = ""
    name: str
    value: float


@action("set_camera_params", ontology=ONTOLOGY, reply=CameraParams, group="vision")
class SetCameraParams(Action):
    camera: str = ""
    brightness: float | None = None
    contrast: float | None = None
    gain: float | None = None
    exposure: float | None = None
    auto_exposure: bool | None = None


@action("get_camera_info", ontology=ONTOLOGY, reply=CameraInfo, group="vision")
class GetCameraInfo(Action):
    camera: str = ""
    resolution: str = "320x240"


# ---------------------------------------------------------------- navigation
@action("move_to", ontology=ONTOLOGY, reply=Done, group="navigation")
class MoveTo(Action):
    """Relative motion in the robot frame at call time."""

    x: float
    y: float = 0.0
    theta: float = 0.0


@action("move_vel", ontology=ONTOLOGY, reply=Done, group="navigation")
class MoveVel(Action):
    """Continuous velocity in the robot frame (m/s, rad/s) until move_stop; y must be 0 on diff drive."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0


@action("move_stop", ontology=ONTOLOGY, reply=Done, group="navigation")
class MoveStop(Action):
    pass


@action("move_along_path", ontology=ONTOLOGY, reply=Done, group="navigation")
class MoveAlongPath(Action):
    poses: list[Pose2D]


@action("look_at_point", ontology=ONTOLOGY, reply=Done, group="navigation")
class LookAtPoint(Action):
    x: float
    y: float
    z: float


@action("get_global_pose", ontology=ONTOLOGY, reply=Pose2D, group="navigation")
class GetGlobalPose(Action):
    pass


@action("set_global_pose", ontology=ONTOLOGY, reply=Done, group="navigation")
class SetGlobalPose(Action):
    x: float
    y: float
    theta: float = 0.0


@action("get_transform", ontology=ONTOLOGY, reply=Transform, group="navigation")
class GetTransform(Action):
    chain: str = "camera"  # camera name, "camera", "head", "laser", "sonar_left", "sonar_right"
    space: str = "robot"  # "robot" (base frame) or "global" (via the estimated pose)


@action("move_joint", ontology=ONTOLOGY, reply=Done, group="navigation")
class MoveJoint(Action):
    joints: list[str]
    angles: list[float]
    speed: float = 0.5  # fraction of the joints' maximum speed (0..1]


@action("get_joint_angles", ontology=ONTOLOGY, reply=JointAngles, group="navigation")
class GetJointAngles(Action):
    joints: list[str] = Field(default_factory=list)  # empty = all


@action("take_predefined_posture", ontology=ONTOLOGY, reply=Done, group="navigation")
class TakePredefinedPosture(Action):
    posture: str
    speed: float = 0.5


@action("rest", ontology=ONTOLOGY, reply=Done, group="navigation")
class Rest(Action):
    pass


# ---------------------------------------------------------------- sensors
@action("get_sonars", ontology=ONTOLOGY, reply=SonarReading, group="sensors")
class GetSonars(Action):
    pass


@action("get_laser_scan", ontology=ONTOLOGY, reply=LaserScan, group="sensors")
class GetLaserScan(Action):
    pass


class LockState(Content):
    resource: str
    held: bool
    holder: str | None = None


@action("lock_resource", ontology=ONTOLOGY, reply=LockState, group="resources")
class LockResource(Action):
    """Paper 003: lock (wait up to timeout_s) or try-lock (wait=False) a device: base, head,
    joints, camera, speaker, microphone. Served by the Core, not by the robot."""

    resource: str
    wait: bool = True
    timeout_s: float = Field(default=10.0, ge=0, le=600)


@action("free_resource", ontology=ONTOLOGY, reply=LockState, group="resources")
class FreeResource(Action):
    resource: str


ROBOT_ACTIONS: dict[str, type[Action]] = {
    n: m for n, m in actions(ONTOLOGY).items() if m.group != "resources"}
