"""Robot-API message models (ontology "robot"): one request model per RobotAPI method.

The Core dispatches generically: ``await getattr(api, req.action_name)(req)`` returns the reply model
named by ``type(req).reply_model``. Units: metres, radians, seconds (simulation time). Poses are in the
GLOBAL (map) frame unless stated otherwise; ``move_to`` is relative to the robot.
Camera optical frame convention: x right, y down, z forward (OpenCV).
"""
from __future__ import annotations

from typing import Callable, Literal

from pydantic import Field, model_validator

from .registry import A, Action, Content, Done, action, actions
from .robot_actions import ACTION_FACTS
from .services.common import Pose2D  # noqa: F401 - one Pose2D for robot and Platform messages

ONTOLOGY = "robot"


def robot_action(name: str, *, reply: type[Content] = Done) -> Callable[[A], A]:
    """@action for the robot ontology: group and idempotency come from the action's row in ACTION_FACTS."""
    row = ACTION_FACTS[name]
    return action(name, ontology=ONTOLOGY, reply=reply, group=row.group, idempotent=row.idempotent)


# ---------------------------------------------------------------- reply / shared contents
class WordSpotted(Content):
    """First matching word heard, or word=None when the timeout expired."""

    word: str | None = None
    text: str | None = None


class Audio(Content):
    """A recording: a 16-bit PCM WAV file, base64; mono unless each microphone was asked for
    (CaptureAudio.array), then one channel per microphone, interleaved, in the order of `microphones`."""

    encoding: str = "wav"
    sample_rate: int
    seconds: float
    data_b64: str
    stamp: float = 0.0  # simulation time of the first sample
    channels: int = 1
    # with array: where each channel's microphone is, in the robot's frame (m: forward, left, up from
    # the point a mono recording is heard at), so a listener can steer the array
    microphones: list[tuple[float, float, float]] = Field(default_factory=list)


class MicrophoneLevel(Content):
    """Sound level at the microphone over `seconds`, in dB relative to full scale."""

    rms_dbfs: float
    peak_dbfs: float
    seconds: float
    stamp: float = 0.0


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
    mount_x: float = 0.0  # how far ahead of the base's centre the sensors sit (m)
    bearing: float = 0.0  # each sonar's axis from the heading (rad): left +bearing, right -bearing


class ContactChange(Content):
    """A contact sensor pressed or released (a NAO's foot bumper or head/hand touch sensor)."""

    sensor: str  # of Contacts.pressed: bumper_left, bumper_right, head_front, head_middle, head_rear, hand_left, hand_right
    kind: Literal["bumper", "touch"]
    pressed: bool
    stamp: float  # simulation time
    seq: int  # 1, 2, ... in the order the robot's contact sensors changed


class Contacts(Content):
    """The robot's contact sensors now, and their changes after a given one."""

    pressed: dict[str, bool]  # every contact sensor of the robot: pressed now
    changes: list[ContactChange] = Field(default_factory=list)  # oldest first (the last CONTACT_BUFFER kept)
    last: int = 0  # the newest change's seq: the next request's `after`
    stamp: float = 0.0  # simulation time of the reading


class DepthImage(Content):
    """A depth camera's image: z along the optical axis (m) per pixel, as a 16-bit PNG of millimetres, 0 where
    the sensor had no return (too near, too far, too oblique). Optical frame as the cameras'."""

    camera: str
    width: int
    height: int
    encoding: str = "png16mm"
    data_b64: str
    stamp: float = 0.0
    range_min: float  # m: nearer returns are missing, as farther than range_max
    range_max: float
    K: list[list[float]]  # pinhole intrinsics of this image (pixel centres at integer coordinates)
    camera_to_robot: list[list[float]]  # optical frame -> robot base frame (4x4) when it was taken


class PoseEstimate(Content):
    """The Core's pose estimate (odometry fused with the global fixes it was given), with its covariance."""

    pose: Pose2D
    covariance: list[list[float]]  # 3x3, of (x m, y m, theta rad)
    std_m: float  # position standard deviation, worst direction
    std_rad: float
    fixes: int = 0  # fixes fused since the Core started
    accepted: bool = True  # add_pose_fix: False when the fix was refused (too far from the estimate)


class LaserScan(Content):
    angle_min: float
    angle_max: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: list[float]
    mount_x: float = 0.0  # how far ahead of the base's centre the scanner sits (m)


# ---------------------------------------------------------------- communication
@robot_action("say", reply=Done)
class Say(Action):
    """Speak `text` (synthesised: the robot's loudspeaker plays it into the room)."""

    text: str
    language: str = "en"
    voice: str = ""  # an eSpeak NG voice, e.g. "en-us", "en-us+f3"; "" = the language's default
    speed: int = Field(default=160, ge=80, le=450)  # words per minute


@robot_action("word_spotting", reply=WordSpotted)
class WordSpotting(Action):
    """Wait for one of `words`: typed utterances (Microphone.hear) within `timeout` wall-clock seconds
    and, with `audio`, a word spoken alone in the room within `timeout` seconds of simulation time."""

    words: list[str]
    timeout: float = 10.0  # wall-clock seconds (speech comes from a person or a scenario script)
    audio: bool = True


MAX_AUDIO_SECONDS = 5.0  # a 16 kHz recording of this length still fits one message (agents/base.py MAX_BODY)
MAX_MICROPHONES = 4  # channels of one capture_audio with array (a NAO's head)
AUDIO_BUFFER_S = 30.0  # the sound a robot's audio device keeps for a capture `since` an earlier time
MAX_AUDIO_B64 = 4 * (44 + 2 * 16000 * int(MAX_AUDIO_SECONDS)) // 3 + 4


@robot_action("capture_audio", reply=Audio)
class CaptureAudio(Action):
    """Record the microphone for `seconds` of simulation time.

    `observe`: only record the time that other motions and waits make pass (a simulation run as fast
    as possible is not stepped for this recording; a listener beside a task must not drive the world).

    `since` (a simulation time, the end of an earlier recording: its stamp + seconds): record from
    then, not from now. The robot's audio device keeps the last AUDIO_BUFFER_S of sound, so a listener
    whose next request comes late (a slow CPU) still gets every sample, only later: the reply holds at
    least `seconds` from `since` (waiting for them as needed) and at most MAX_AUDIO_SECONDS (what has
    already passed is returned at once; ask again for the rest). Its `stamp` is later than `since`
    only where `since` was older than the buffer: that sound is lost."""

    seconds: float = Field(default=3.0, gt=0, le=MAX_AUDIO_SECONDS)
    sample_rate: Literal[8000, 16000] = 16000
    observe: bool = False
    since: float | None = Field(default=None, ge=0)
    # each of the robot's microphones as a channel of its own (a NAO's four; one where a robot has one),
    # 16 kHz only; a reply then holds at most MAX_AUDIO_SECONDS / MAX_MICROPHONES, to fit one message
    array: bool = False

    @model_validator(mode="after")
    def _fits_one_message(self) -> CaptureAudio:
        if self.array and (self.seconds > MAX_AUDIO_SECONDS / MAX_MICROPHONES or self.sample_rate != 16000):
            raise ValueError(f"capture_audio with array: at most {MAX_AUDIO_SECONDS / MAX_MICROPHONES:g} s, at 16000 Hz")
        return self


@robot_action("play_audio", reply=Done)
class PlayAudio(Action):
    """Play a mono 16-bit PCM WAV (16 kHz) on the loudspeaker; returns when it has been played."""

    data_b64: str = Field(min_length=1, max_length=MAX_AUDIO_B64)


@robot_action("microphone_energy", reply=MicrophoneLevel)
class MicrophoneEnergy(Action):
    """The sound level at the microphone over a short time."""

    seconds: float = Field(default=0.2, gt=0, le=2.0)


# ---------------------------------------------------------------- vision
@robot_action("capture_image", reply=Image)
class CaptureImage(Action):
    """One image of a camera (PNG, base64) at a resolution; the robot's main camera by default."""

    camera: str = ""  # "" = the robot's main camera
    resolution: str = "320x240"  # "WxH" or QQVGA/QVGA/VGA


@robot_action("set_camera_param", reply=CameraParams)
class SetCameraParam(Action):
    """Set one image adjustment (brightness, contrast, gain, exposure, auto_exposure); answers them
    all."""

    camera: str = ""
    name: str
    value: float


@robot_action("set_camera_params", reply=CameraParams)
class SetCameraParams(Action):
    """Set the given image adjustments (none given: change nothing); answers them all."""

    camera: str = ""
    brightness: float | None = None
    contrast: float | None = None
    gain: float | None = None
    exposure: float | None = None
    auto_exposure: bool | None = None


@robot_action("get_camera_info", reply=CameraInfo)
class GetCameraInfo(Action):
    """The camera's pinhole intrinsics at a resolution (K, P, fields of view)."""

    camera: str = ""
    resolution: str = "320x240"


# ---------------------------------------------------------------- navigation
@robot_action("move_to", reply=Done)
class MoveTo(Action):
    """Relative motion in the robot frame at call time."""

    x: float  # m forward
    y: float = 0.0  # m to the left
    theta: float = 0.0  # rad, counter-clockwise: the heading at the end, relative to now


@robot_action("move_vel", reply=Done)
class MoveVel(Action):
    """Continuous velocity in the robot frame (m/s, rad/s) until move_stop; y must be 0 on diff drive."""

    x: float = 0.0  # m/s forward
    y: float = 0.0  # m/s to the left (a NAO only)
    theta: float = 0.0  # rad/s, counter-clockwise


@robot_action("move_stop", reply=Done)
class MoveStop(Action):
    """Stop the base now (a move_vel velocity or a path)."""


@robot_action("move_along_path", reply=Done)
class MoveAlongPath(Action):
    """Follow a path of global poses (a plan's `path`) to its end; progress comes as feedback."""

    poses: list[Pose2D]


@robot_action("look_at_point", reply=Done)
class LookAtPoint(Action):
    """Turn the head (NAO) or camera so the camera looks at a point of the global frame."""

    x: float  # m, global frame (through the robot's pose estimate)
    y: float
    z: float  # m above the floor


@robot_action("get_global_pose", reply=Pose2D)
class GetGlobalPose(Action):
    """The robot's own estimate of its pose (odometry, drifting as it moves; set_global_pose corrects
    it), not the truth."""


@robot_action("set_global_pose", reply=Done)
class SetGlobalPose(Action):
    """Correct the robot's pose estimate (after localizing); odometry goes on from there."""

    x: float  # m, global frame
    y: float
    theta: float = 0.0  # rad, counter-clockwise from +x


@robot_action("get_transform", reply=Transform)
class GetTransform(Action):
    """A frame's pose as a 4x4 matrix, in the robot's base frame or globally (through the estimated
    pose)."""

    chain: str = "camera"  # camera name, "camera", "head", "laser", "sonar_left", "sonar_right"
    space: str = "robot"  # "robot" (base frame) or "global" (via the estimated pose)


@robot_action("move_joint", reply=Done)
class MoveJoint(Action):
    """Move joints to angles (rad) at a fraction of their maximum speed."""

    joints: list[str]
    angles: list[float]
    speed: float = 0.5  # fraction of the joints' maximum speed (0..1]


@robot_action("get_joint_angles", reply=JointAngles)
class GetJointAngles(Action):
    """The angles (rad) of the given joints, or of all."""

    joints: list[str] = Field(default_factory=list)  # empty = all


@robot_action("take_predefined_posture", reply=Done)
class TakePredefinedPosture(Action):
    """Take a named posture of the robot (a NAO's Stand, Crouch, Sit, ...)."""

    posture: str
    speed: float = 0.5


@robot_action("rest", reply=Done)
class Rest(Action):
    """Stop the base and take the robot's rest posture."""


# ---------------------------------------------------------------- sensors
@robot_action("get_sonars", reply=SonarReading)
class GetSonars(Action):
    """The two sonars' ranges (a NAO; an Elektron has a laser scanner)."""


@robot_action("get_laser_scan", reply=LaserScan)
class GetLaserScan(Action):
    """One scan of the laser range finder (an Elektron; a NAO has sonars)."""


CONTACT_BUFFER = 100  # contact changes a robot keeps for get_contacts `after`


@robot_action("get_contacts", reply=Contacts)
class GetContacts(Action):
    """The contact sensors (a NAO's foot bumpers, head and hand touch sensors): which are pressed now and
    every press and release after the change numbered `after` (a reply's `last`; None: no past changes)."""

    after: int | None = Field(default=None, ge=0)


@robot_action("capture_depth", reply=DepthImage)
class CaptureDepth(Action):
    """One image of a depth camera (an Elektron's Kinect), with a real sensor's noise and missing returns."""

    camera: str = ""  # "" = the robot's first depth camera
    resolution: str = "320x240"  # "WxH" or QQVGA/QVGA/VGA


# ---------------------------------------------------------------- localization (served by the Core)
@robot_action("get_pose_estimate", reply=PoseEstimate)
class GetPoseEstimate(Action):
    """The Core's own estimate of the robot's pose and its covariance: the robot's odometry fused with the
    global fixes given by add_pose_fix (paper 001's relative localization in the Core). Served by the Core."""


@robot_action("add_pose_fix", reply=PoseEstimate)
class AddPoseFix(Action):
    """A global pose fix (e.g. from QR landmarks) for the Core's estimate, with its standard deviations;
    answers the fused estimate. A fix too far from the estimate for both uncertainties is refused
    (accepted=False) unless `gate` is False. Served by the Core."""

    x: float  # m, global frame
    y: float
    theta: float  # rad
    std_m: float = Field(gt=0, le=100)
    std_rad: float = Field(gt=0, le=10)
    gate: bool = True


class LockState(Content):
    resource: str
    held: bool
    holder: str | None = None


@robot_action("lock_resource", reply=LockState)
class LockResource(Action):
    """Paper 003: lock (wait up to timeout_s) or try-lock (wait=False) a device: base, head,
    joints, camera, speaker, microphone. Served by the Core, not by the robot."""

    resource: str
    wait: bool = True
    timeout_s: float = Field(default=10.0, ge=0, le=600)


@robot_action("free_resource", reply=LockState)
class FreeResource(Action):
    """Release a device lock this run holds (lock_resource)."""

    resource: str


ROBOT_ACTIONS: dict[str, type[Action]] = {  # served by the robot (RobotAPI); the others by the Core itself
    n: m for n, m in actions(ONTOLOGY).items() if not ACTION_FACTS[n].core}
