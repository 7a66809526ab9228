"""Vision services: face and human detection, face recognition of registered people, object learn /
find / clear, scene (room) recognition (QR: localization.py)."""
from __future__ import annotations

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, Done, action

GROUP = "vision"


class Box(Content):
    x: int
    y: int
    width: int
    height: int


class Detections(Content):
    boxes: list[Box]


@action("face_detection", ontology="platform", reply=Detections, group=GROUP, idempotent=True)
class FaceDetect(ServiceRequest):
    """The faces in an image (OpenCV's Haar cascade): a box each."""

    image_b64: str


@action("human_detection", ontology="platform", reply=Detections, group=GROUP, idempotent=True)
class HumanDetect(ServiceRequest):
    """The people standing in an image (OpenCV's HOG detector): a box each."""

    image_b64: str


@action("object_detection_learn_object", ontology="platform", reply=Done, group=GROUP)
class LearnObject(ServiceRequest):
    """Learn an object from one image of it (its features), under `name`."""

    name: str = Field(min_length=1, max_length=64)
    image_b64: str


class FoundObject(Content):
    name: str
    matches: int
    corners: list[list[float]]  # the model image's outline in the query image (px)


class FoundObjects(Content):
    objects: list[FoundObject]


@action("object_detection_find_objects", ontology="platform", reply=FoundObjects, group=GROUP, idempotent=True)
class FindObjects(ServiceRequest):
    """The learned objects found in an image (feature matching), best first."""

    image_b64: str
    limit: int = Field(default=5, ge=1, le=50)
    min_matches: int = Field(default=15, ge=4)


@action("object_detection_clear_models", ontology="platform", reply=Done, group=GROUP)
class ClearObjects(ServiceRequest):
    """Forget every object learned for this user."""


# ------------------------------------------------------------------ face recognition
MAX_FACE_SAMPLES = 20


class FaceLearned(Content):
    name: str
    used: int  # images a face was found in and learned
    skipped: list[str] = []  # why the others were not ("image 2: no face found")
    samples: int  # kept for this person now


@action("face_recognition_learn", ontology="platform", reply=FaceLearned, group=GROUP)
class LearnFace(ServiceRequest):
    """Register a person from a few photographs (1-10), each with that person's face the largest in it;
    learning again under the same name adds to what was learned (at most MAX_FACE_SAMPLES kept)."""

    name: str = Field(min_length=1, max_length=64, pattern=r"^[^\x00-\x1f]+$")
    images_b64: list[str] = Field(min_length=1, max_length=10)


class RecognizedFace(Content):
    box: Box
    name: str  # the registered person, or "" for someone unknown
    distance: float  # to that person's nearest sample (descriptor space; below `threshold`: recognized)
    nearest: str = ""  # the nearest registered person, even when too far to be them


class RecognizedFaces(Content):
    faces: list[RecognizedFace]  # largest face first


@action("face_recognition_recognize", ontology="platform", reply=RecognizedFaces, group=GROUP, idempotent=True)
class RecognizeFaces(ServiceRequest):
    """Who is in an image: each face found, with the closest learned person within `threshold`."""

    image_b64: str
    threshold: float = Field(default=0.6, gt=0.0, le=2.0)  # dlib's rule: one person within 0.6
    limit: int = Field(default=10, ge=1, le=50)


class FacePerson(Content):
    name: str
    samples: int


class FacePeople(Content):
    people: list[FacePerson]


@action("face_recognition_list", ontology="platform", reply=FacePeople, group=GROUP, idempotent=True)
class ListFaces(ServiceRequest):
    """The people learned for this user (face_recognition_learn)."""


@action("face_recognition_forget", ontology="platform", reply=FacePeople, group=GROUP)
class ForgetFace(ServiceRequest):
    """Forget one person (`name`), or everyone (`name` empty)."""

    name: str = Field(default="", max_length=64)


# ------------------------------------------------------------------ scene recognition
@action("scene_recognition_learn", ontology="platform", reply=Done, group=GROUP)
class LearnScene(ServiceRequest):
    """Camera images taken in `room` of the user's home `home_id` (views from several places and
    headings make it robust; learning again adds views)."""

    room: str = Field(min_length=1, max_length=64)
    images_b64: list[str] = Field(min_length=1, max_length=12)
    home_id: str = Field(default="home", min_length=1, max_length=64)


class SceneGuess(Content):
    room: str
    distance: float  # mean over the images of the distance to the room's nearest learned view (0..2)
    votes: int = 0  # image features that match the room's learned views better than anything else


class SceneReply(Content):
    room: str  # the recognized room, "" when none is near enough
    distance: float
    votes: int = 0
    candidates: list[SceneGuess]  # every learned room, the best first


@action("scene_recognition_recognize", ontology="platform", reply=SceneReply, group=GROUP, idempotent=True)
class RecognizeScene(ServiceRequest):
    """Which room the images were taken in: one view, or a look-around (several headings from one place)
    for a surer answer."""

    images_b64: list[str] = Field(min_length=1, max_length=12)
    home_id: str = Field(default="home", min_length=1, max_length=64)
    max_distance: float = Field(default=0.5, gt=0.0)  # without enough feature votes, nearer than this


@action("scene_recognition_forget", ontology="platform", reply=Done, group=GROUP)
class ForgetScenes(ServiceRequest):
    """Forget the learned views of one room of a home, or of all its rooms (`room` empty)."""

    home_id: str = Field(default="home", min_length=1, max_length=64)
    room: str = Field(default="", max_length=64)
