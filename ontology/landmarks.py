"""Messages of the SDK's landmark localization between a task and its RApp's Cloud Agent
(rapps/sdk/localize.py on the task's side, rapps/sdk/landmark_cloud.py on the Cloud Agent's): find
the home's QR landmarks in one frame, then the robot's pose from every code seen so far."""
from __future__ import annotations

from .registry import Action, Content, action
from .services.common import CameraIntrinsics, Pose2D
from .services.home import LandmarkSpec

ONTOLOGY = "cloud.landmarks"


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
    """Find the known QR landmarks in one image (camera optical frame -> robot base given); each
    landmark's own printed size (`LandmarkSpec.size_m`) gives its distance."""

    image_b64: str
    camera: CameraIntrinsics
    camera_to_robot: list[list[float]]
    landmarks: dict[str, LandmarkSpec]
    max_distance_m: float = 4.5
    # the codes the frame was taken to see: once they are all found the detector stops (its pass for
    # codes seen obliquely runs only when one is missing); empty: every pass
    expect: list[str] = []


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
    """Robot pose from the observations of one localization's frames."""

    observations: list[Observation]
    landmarks: dict[str, LandmarkSpec]
    prior: Pose2D | None = None  # current estimate: picks between a single code's ambiguous poses
