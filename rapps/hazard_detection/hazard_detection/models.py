"""Messages between the hazard-detection task and its Cloud Agent."""
from ontology.registry import Action, Content, action
from ontology.services.common import CameraIntrinsics, Pose2D
from ontology.services.home import LandmarkSpec

ONTOLOGY = "cloud.hazard-detection"


class Localization(Content):
    found: bool
    pose: Pose2D | None = None
    markers: list[str] = []  # texts of the landmarks used
    distance_m: float | None = None  # distance of the nearest used landmark


@action("localize", ontology=ONTOLOGY, reply=Localization)
class Localize(Action):
    """Robot pose from the QR landmarks seen in one image (camera optical frame -> robot base)."""

    image_b64: str
    camera: CameraIntrinsics
    camera_to_robot: list[list[float]]
    landmarks: dict[str, LandmarkSpec]
    max_distance_m: float = 4.5
