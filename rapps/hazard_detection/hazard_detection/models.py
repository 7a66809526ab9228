"""Messages between the hazard-detection task and its Cloud Agent, and the data of its reports."""
from typing import Literal

from ontology.registry import Action, Content, action
from ontology.services.common import CameraIntrinsics
from ontology.services.home import DoorShape, DoorwaySpec, RoomSpec

ONTOLOGY = "cloud.hazard-detection"


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
