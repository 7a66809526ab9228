"""Navigation service messages (paper 001): map upload / listing, 2-D path planning and a per-user
layer of temporary obstacles (a box in a doorway, a closed door, a person standing still) that plans
go round until the RApp clears them or they expire."""
from __future__ import annotations

from pydantic import Field, model_validator

from ..platform import ServiceRequest
from ..registry import Content, action
from .common import Pose2D

GROUP = "navigation"

# plan_found codes, as in the original RAPP path_planning_plan_path_2d
PLAN_NOT_FOUND = 0
PLAN_FOUND = 1
PLAN_UNKNOWN_MAP = 2
PLAN_UNKNOWN_ROBOT = 3
PLAN_UNKNOWN_ALGORITHM = 4


class MapInfo(Content):
    map_id: str
    width: int  # cells
    height: int  # cells
    resolution: float  # m / cell
    origin: list[float]  # x, y, yaw of the lower-left cell (ROS map_server convention)
    shared: bool = False  # preloaded map visible to every user


@action("path_planning_upload_map", ontology="platform", reply=MapInfo, group=GROUP)
class UploadMap(ServiceRequest):
    """A ROS map_server map: PNG (base64) + its YAML text (resolution, origin, thresholds, negate)."""

    map_id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    png_b64: str = Field(min_length=1)
    yaml_text: str = Field(min_length=1)


class MapList(Content):
    maps: list[MapInfo]


@action("path_planning_list_maps", ontology="platform", reply=MapList, group=GROUP, idempotent=True)
class ListMaps(ServiceRequest):
    """The maps this user may plan on (their own and the shared ones)."""


class PlanPathReply(Content):
    plan_found: int  # 0 none, 1 found, 2 unknown map, 3 unknown robot type, 4 unknown algorithm
    path: list[Pose2D] = []
    reason: str = ""
    length_m: float = 0.0
    planning_time_s: float = 0.0
    clearance_m: float = 0.0  # margin kept beyond the robot's footprint along this path
    obstacles_used: int = 0  # temporary obstacle marks on the cost map this plan was made on


@action("path_planning_plan_path_2d", ontology="platform", reply=PlanPathReply, group=GROUP, idempotent=True)
class PlanPath2D(ServiceRequest):
    """Plan from start to goal for a robot type ("nao", "elektron") with an algorithm
    ("astar", "dijkstra", "rrtconnect", "rrtstar", "bitstar", "prmstar")."""

    robot_type: str
    algorithm: str = "astar"
    map_id: str
    start: Pose2D
    goal: Pose2D
    waypoint_spacing_m: float = Field(default=0.3, gt=0.01, le=5.0)
    time_limit_s: float = Field(default=1.0, gt=0.0, le=10.0)  # sampling planners only
    # extra distance kept from obstacles where the map allows it (less in narrower passages): a
    # path along a door frame makes forward range sensors see it within the robots' safety distance
    clearance_m: float = Field(default=0.20, ge=0.0, le=1.0)
    use_obstacles: bool = True  # plan round this user's temporary obstacle marks on the map


class TempObstacle(Content):
    """A temporary obstacle mark: a disc in the map frame that plans of its owner go round."""

    id: str
    x: float  # m, map frame
    y: float
    radius_m: float
    expires_in_s: float  # seconds left before the mark is dropped
    note: str = ""  # what the RApp took it for ("box", "door d1 closed")


class ObstacleLayer(Content):
    """The caller's live marks on one map, after the request."""

    map_id: str
    obstacles: list[TempObstacle]
    added: str = ""  # add_obstacle: the new mark's id, "" when it was not added (skip_within_m)


@action("path_planning_add_obstacle", ontology="platform", reply=ObstacleLayer, group=GROUP)
class AddObstacle(ServiceRequest):
    """Mark a temporary obstacle (disc) on a map: the caller's next plans on it go round it."""

    map_id: str
    x: float = Field(allow_inf_nan=False)  # m, map frame: the obstacle's centre
    y: float = Field(allow_inf_nan=False)
    radius_m: float = Field(gt=0.02, le=1.5, allow_inf_nan=False)
    ttl_s: float = Field(default=120.0, gt=0.0, le=3600.0)  # dropped after this, unless cleared first
    note: str = Field(default="", max_length=200)
    # not added when the map's own obstacles lie this close to (x, y): what the robot met is mapped
    # already (its pose estimate was off), and a disc there would only narrow a passage
    skip_within_m: float = Field(default=0.0, ge=0.0, le=1.0)


@action("path_planning_clear_obstacles", ontology="platform", reply=ObstacleLayer, group=GROUP)
class ClearObstacles(ServiceRequest):
    """Drop the caller's marks centred within radius_m of (x, y), a place seen free again; all=True: all marks."""

    map_id: str
    x: float | None = Field(default=None, allow_inf_nan=False)  # m, map frame
    y: float | None = Field(default=None, allow_inf_nan=False)
    radius_m: float = Field(default=0.5, ge=0.0, le=20.0)
    all: bool = False

    @model_validator(mode="after")
    def _place_or_all(self) -> ClearObstacles:
        if not self.all and (self.x is None or self.y is None):
            raise ValueError("give the place seen free (x, y) or all=True")
        return self


@action("path_planning_list_obstacles", ontology="platform", reply=ObstacleLayer, group=GROUP, idempotent=True)
class ListObstacles(ServiceRequest):
    """The caller's live temporary obstacle marks on a map."""

    map_id: str
