"""Home description a user keeps on the Platform: the map id, the landmark (QR) map and the list of
possible hazards with where to stand and where to look to check each one (hazard-detection RApp)."""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, action
from .common import Pose2D
from .localization import Landmark

GROUP = "home"


class DoorShape(Content):
    """Hinge on the floor (m), closed direction hinge -> latch (deg), leaf width (m) and the way the
    leaf swings open: "left" turns it counter-clockwise seen from above (as the house file says), None
    when the owner did not say."""

    hinge: list[float] = Field(min_length=2, max_length=2)
    closed_yaw_deg: float
    width_m: float = Field(default=0.9, gt=0)
    opens: Literal["left", "right"] | None = None


DoorSide = Literal["front", "swing"]


class DoorCheckPose(Content):
    """Where to stand on one side of a doorway to check its door, and the floor point to look at:
    "front" is the side the leaf does not swing to (in front of the wall, the whole leaf seen
    obliquely), "swing" the side it swings into (beside the open leaf's line, looking at the hinge).
    Both stand outside the leaf's sweep."""

    side: DoorSide
    stand: Pose2D  # global frame, facing the look-at point
    look_at: list[float] = Field(min_length=3, max_length=3)  # x, y, z (z = 0: the floor at the hinge)
    room: str | None = None  # the room the stand is in (None: in no named room)
    clearance_m: float | None = None  # distance from the stand to the nearest wall or furniture (not doors)


class DoorwaySpec(Content):
    """A door of the home as the map's owner knows it (where, how wide, which way it swings, where to
    check it from), never its state: a plan monitor that finds the way blocked in a doorway can say
    which door is closed."""

    id: str
    door: DoorShape
    rooms: list[str] = []  # the rooms it joins (when known)
    checks: list[DoorCheckPose] = []  # a check pose from each side (front, swing) where the home knows them

    def check_from(self, side: DoorSide) -> DoorCheckPose | None:
        """The check pose on `side` ("front" or "swing"), None when the home gives none."""
        return next((c for c in self.checks if c.side == side), None)


class RoomSpec(Content):
    """A named room: its axis-aligned rectangle x0, y0, x1, y1 (m, global frame)."""

    name: str
    rect: list[float] = Field(min_length=4, max_length=4)


class HazardSpec(Content):
    id: str
    type: Literal["door", "lamp"]
    room: str | None = None  # the room it is checked from (a lamp's room; a door: where the robot stands)
    stand: Pose2D  # where the robot stands to check it (global frame)
    look_at: list[float] = Field(min_length=3, max_length=3)  # x, y, z of the point to look at
    door: DoorShape | None = None


class LandmarkSpec(Landmark):
    """A QR panel of the home: its pose (Landmark), the side of its symbol and the room it faces."""

    size_m: float = Field(default=0.25, gt=0)  # QR symbol side without quiet zone: detect it with this size
    room: str | None = None  # the room it faces into


class HomeInfo(Content):
    home_id: str = Field(min_length=1, max_length=64)
    map_id: str  # a map uploaded with path_planning_upload_map (or a shared one)
    hazards: list[HazardSpec] = []
    landmarks: dict[str, LandmarkSpec] = {}  # keyed by the text encoded in the QR code
    rooms: list[RoomSpec] = []
    doors: list[DoorwaySpec] = []  # every door of the home (hazards or not)


@action("home_upload_info", ontology="platform", reply=HomeInfo, group=GROUP)
class UploadHomeInfo(ServiceRequest):
    """Store a home description for this user (replaces one with the same home_id)."""

    info: HomeInfo


@action("home_get_info", ontology="platform", reply=HomeInfo, group=GROUP, idempotent=True)
class GetHomeInfo(ServiceRequest):
    """The home description the owner uploaded (map id, rooms, doors with their check poses, landmarks
    with their sizes, hazards)."""

    home_id: str = "home"
