"""Navigation service messages (paper 001): map upload / listing and 2-D path planning."""
from __future__ import annotations

from pydantic import Field

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
    pass


class PlanPathReply(Content):
    plan_found: int  # 0 none, 1 found, 2 unknown map, 3 unknown robot type, 4 unknown algorithm
    path: list[Pose2D] = []
    reason: str = ""
    length_m: float = 0.0
    planning_time_s: float = 0.0
    clearance_m: float = 0.0  # margin kept beyond the robot's footprint along this path


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
