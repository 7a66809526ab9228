"""Face recognition of registered people (paper 000 sec. 5.3: "human detection as well as face detection
and recognition"): a user registers a person from a few photographs; a camera image then names each
face it finds, or says it is someone unknown.

- detection: OpenCV's frontal-face Haar cascade (vision.face_detector), on the image scaled to at most
  DETECT_SIDE pixels (a 1920-pixel photograph would take a second);
- the face chip: face-api.js's 68-point landmark network on the cascade's box, then the square face-api
  aligns a face with (eyes and mouth), cut from the full-resolution image and scaled to 150x150;
- the descriptor: face-api.js's ResNet, 128 numbers (both networks: agents/services/face_net.py);
- the decision: the nearest registered sample; within `threshold` (0.6, dlib's rule) it is that
  person, else "" (unknown).

Per-user galleries are kept in the Platform's saved data (kind "face": one record per person, its
descriptors as an array; agents/services/saved.py); images are not kept. Measured accuracy on real
photographs and on renders of simulated people: docs/face-recognition.md.
"""
from __future__ import annotations

import threading

import cv2
import numpy as np

from ontology.errors import ErrorCode
from ontology.services.vision import (
    MAX_FACE_SAMPLES, Box, FaceLearned, FacePeople, FacePerson, ForgetFace, LearnFace, ListFaces, RecognizedFace,
    RecognizedFaces, RecognizeFaces,
)

from .context import ServiceContext
from .errors import ServiceError
from .face_net import CHIP, descriptor, dlib_box, landmarks
from .images import decode_image
from .saved import pack_arrays, unpack_arrays
from .vision import face_detector

DETECT_SIDE = 800  # the longer side the cascade looks at (px)
MIN_FACE_PX = 24


def find_faces(img: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Frontal faces of a BGR image as (x, y, w, h) in its pixels, largest first."""
    h, w = img.shape[:2]
    k = min(1.0, DETECT_SIDE / max(h, w))
    small = cv2.resize(img, (round(w * k), round(h * k)), interpolation=cv2.INTER_AREA) if k < 1 else img
    # no histogram equalization: in a robot's view of a room, grey walls and ceiling make most of the
    # histogram and equalizing it washed the faces out (a face 60 px wide at 1.5 m was missed)
    gray = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY) if small.ndim == 3 else small
    rects = face_detector().detectMultiScale(gray, scaleFactor=1.1, minNeighbors=5,
                                             minSize=(MIN_FACE_PX, MIN_FACE_PX))
    boxes = [tuple(int(round(v / k)) for v in r) for r in rects]
    return sorted(boxes, key=lambda b: -b[2] * b[3])


def face_chip(img: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """The 150x150 RGB chip the descriptor network reads: the 68 landmarks found in the detector's box,
    the square face-api aligns with from them (eyes and mouth), cut and scaled (zeros beyond the image)."""
    rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB if img.ndim == 3 else cv2.COLOR_GRAY2RGB)
    x, y, w, h = box
    points = landmarks(rgb[y:y + h, x:x + w]) + np.float32([x, y])
    bx, by, side = dlib_box(points)
    k = CHIP / side
    m = np.float32([[k, 0, -bx * k], [0, k, -by * k]])
    return cv2.warpAffine(rgb, m, (CHIP, CHIP), flags=cv2.INTER_AREA if k < 1 else cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT)


def describe(img: np.ndarray, box) -> np.ndarray:
    return descriptor(face_chip(img, box))


class FaceGallery:
    """Per user: person -> descriptors [n, 128]; kept in `saved` if given."""

    KIND = "face"

    def __init__(self, saved=None) -> None:
        self.lock = threading.Lock()
        self.people: dict[str, dict[str, np.ndarray]] = {}
        self._saved = saved
        for rec in saved.records(self.KIND) if saved is not None else ():
            self.people.setdefault(rec.user, {})[rec.key] = unpack_arrays(rec.blob)["descriptors"]

    def of(self, user: str) -> dict[str, np.ndarray]:
        with self.lock:
            return dict(self.people.get(user, {}))

    def put(self, user: str, name: str, descriptors: np.ndarray) -> None:
        """Replace a person's samples (the newest MAX_FACE_SAMPLES of them)."""
        descriptors = np.asarray(descriptors, np.float32)[-MAX_FACE_SAMPLES:]
        if self._saved is not None:
            self._saved.put(self.KIND, user, name, {"samples": len(descriptors)},
                            pack_arrays(descriptors=descriptors))
        with self.lock:
            self.people.setdefault(user, {})[name] = descriptors

    def forget(self, user: str, name: str = "") -> None:
        if self._saved is not None:
            self._saved.delete(self.KIND, user, name or None)
        with self.lock:
            if name:
                self.people.get(user, {}).pop(name, None)
            else:
                self.people.pop(user, None)


def gallery(ctx: ServiceContext) -> FaceGallery:
    return ctx.state.store("faces", lambda: FaceGallery(ctx.state.saved))


def _people(ctx: ServiceContext) -> FacePeople:
    return FacePeople(people=[FacePerson(name=n, samples=len(d)) for n, d in sorted(gallery(ctx).of(ctx.user).items())])


def learn_face(req: LearnFace, ctx: ServiceContext) -> FaceLearned:
    found, skipped = [], []
    for i, b64 in enumerate(req.images_b64, 1):
        img = decode_image(b64, f"images_b64[{i - 1}]")
        boxes = find_faces(img)
        if not boxes:
            skipped.append(f"image {i}: no frontal face found")
            continue
        found.append(describe(img, boxes[0]))
    if not found:
        raise ServiceError(f"no frontal face found in any of the {len(req.images_b64)} images of {req.name!r}",
                           ErrorCode.NO_FEATURES)
    store = gallery(ctx)
    before = store.of(ctx.user).get(req.name, np.zeros((0, len(found[0])), np.float32))
    store.put(ctx.user, req.name, np.vstack([before, *found]))
    return FaceLearned(name=req.name, used=len(found), skipped=skipped, samples=len(store.of(ctx.user)[req.name]))


def nearest(known: dict[str, np.ndarray], d: np.ndarray) -> tuple[str, float]:
    """The registered person nearest to descriptor d, and the distance to their nearest sample."""
    best = ("", float("inf"))
    for name, samples in known.items():
        dist = float(np.min(np.linalg.norm(samples - d, axis=1)))
        if dist < best[1]:
            best = (name, dist)
    return best


def recognize_faces(req: RecognizeFaces, ctx: ServiceContext) -> RecognizedFaces:
    known = gallery(ctx).of(ctx.user)
    if not known:
        raise ServiceError("no faces registered yet for this user (face_recognition_learn)", ErrorCode.NO_MODELS)
    img = decode_image(req.image_b64)
    out = []
    for box in find_faces(img)[:req.limit]:
        name, dist = nearest(known, describe(img, box))
        out.append(RecognizedFace(box=Box(x=box[0], y=box[1], width=box[2], height=box[3]),
                                  name=name if dist < req.threshold else "", distance=round(dist, 4), nearest=name))
    return RecognizedFaces(faces=out)


def list_faces(req: ListFaces, ctx: ServiceContext) -> FacePeople:
    return _people(ctx)


def forget_face(req: ForgetFace, ctx: ServiceContext) -> FacePeople:
    if req.name and req.name not in gallery(ctx).of(ctx.user):
        raise ServiceError(f"no person {req.name!r} registered for this user", ErrorCode.NOT_FOUND)
    gallery(ctx).forget(ctx.user, req.name)
    return _people(ctx)
