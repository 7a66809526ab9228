"""Messages between the hazard-detection task and its Cloud Agent, and the data of its reports."""
from typing import Literal

from ontology.registry import Action, Content, action
from ontology.services.common import CameraIntrinsics, Pose2D
from ontology.services.home import DoorShape, DoorwaySpec, LandmarkSpec, RoomSpec

ONTOLOGY = "cloud.hazard-detection"


class Observation(Content):
    """One QR landmark seen: its centre in the robot base frame and the pose it alone implies."""

    text: str
    in_robot: list[float]  # x, y, z of the code centre in the robot base frame (m)
    poses: list[Pose2D]  # robot poses from this code alone: both planar-ambiguity solutions, best first
    distance_m: float
    corners: list[list[float]] = []  # refined image corners (TL, TR, BR, BL), pixels
    camera: CameraIntrinsics | None = None  # intrinsics of the image the corners are in
    camera_to_robot: list[list[float]] = []  # camera optical frame -> robot base when the image was taken


class Observations(Content):
    items: list[Observation] = []


@action("observe", ontology=ONTOLOGY, reply=Observations)
class Observe(Action):
    """Find the known QR landmarks in one image (camera optical frame -> robot base given)."""

    image_b64: str
    camera: CameraIntrinsics
    camera_to_robot: list[list[float]]
    landmarks: dict[str, LandmarkSpec]
    max_distance_m: float = 4.5


class Localization(Content):
    found: bool
    pose: Pose2D | None = None
    markers: list[str] = []  # texts of the landmarks used
    method: str = ""  # "points" (2+ landmarks) or "single" (one code's pose), "+fit" when refined
    rms_px: float | None = None  # reprojection error of the refined pose (all corners of all views)
    std_m: float | None = None  # position standard deviation of the refined pose (worst direction)
    std_theta_rad: float | None = None  # heading standard deviation of the refined pose


@action("solve_pose", ontology=ONTOLOGY, reply=Localization)
class SolvePose(Action):
    """Robot pose from the observations of one head sweep."""

    observations: list[Observation]
    landmarks: dict[str, LandmarkSpec]
    prior: Pose2D | None = None  # current estimate: picks between a single code's ambiguous poses


class CameraSpec(Content):
    """The robot's camera at the check's resolution: intrinsics, size, height above the floor and how
    far ahead of the base's centre it sits."""

    intrinsics: CameraIntrinsics
    width: int
    height: int
    z: float
    ahead: float = 0.0


class DoorViewSpec(Content):
    """A stand facing the hinge and where to look from it (view.DoorView)."""

    x: float
    y: float
    theta: float
    look: list[float]
    margin: float
    distance_m: float
    bearing_deg: float


class DoorViewList(Content):
    views: list[DoorViewSpec] = []


@action("door_views", ontology=ONTOLOGY, reply=DoorViewList)
class DoorViews(Action):
    """Where to stand to check a door with the image method, best first (view.door_views)."""

    door: DoorShape
    robot_side: list[float]  # a point on the robot's side of the door (x, y)
    camera: CameraSpec
    rooms: list[RoomSpec] = []
    doors: list[DoorwaySpec] = []
    room: RoomSpec | None = None  # the room the robot checks from
    robot_radius_m: float = 0.35
    open_threshold_deg: float = 5.0
    limit: int = 4


class HazardReport(Content):
    """What the task found at one hazard: the data of its report to the Core (`data["hazard"]`; the
    report's text says the same to the user), read back by scenarios/hazard.py to score the run."""

    id: str
    type: Literal["door", "lamp", "route"]  # route: the only way to a hazard is blocked (id "route-<hazard>")
    state: Literal["open", "closed", "on", "off", "unknown", "blocked"]  # unknown: not reached or not checked
    hazard: bool | None  # None when unknown
    blocked_by: list[str] = []  # routes: what closes the way (e.g. "door d2")
    angle_deg: float | None = None  # doors: the estimated opening angle
    method: str | None = None  # doors: how the angle was estimated
    light_level: float | None = None  # lamps
    confidence: float | None = None  # 0..1: how far the check's evidence can be trusted (its service's answer)
    looks: int = 1  # how many views it took (a frame without usable lines: the robot moved and looked again)
