"""Face / human detection (OpenCV's bundled Haar cascade / HOG people detector, OpenCV 4.x)
and per-user object learning and recognition (ORB features, BFMatcher, RANSAC homography).

The HOG detector crashes the process (segfault) on images smaller than its 64x128 window, so
images are padded first; the padding (a replicated border) also finds people cut by the frame.
OpenCV 5's main package moved CascadeClassifier and HOGDescriptor out of objdetect; with such a
build face and human detection raise ServiceError(code=ErrorCode.UNAVAILABLE).
"""
from __future__ import annotations

import os
import threading

import cv2
import numpy as np

from ontology.registry import Done
from ontology.services.vision import (
    Box,
    ClearObjects,
    Detections,
    FaceDetect,
    FindObjects,
    FoundObject,
    FoundObjects,
    HumanDetect,
    LearnObject,
)
from ontology.errors import ErrorCode

from .context import ServiceContext
from .errors import ServiceError
from .images import decode_image
from .saved import pack_arrays, unpack_arrays

_local = threading.local()  # OpenCV detectors are not shared between threads


def _cascade_path() -> str | None:
    base = getattr(getattr(cv2, "data", None), "haarcascades", "") or ""
    path = os.path.join(base, "haarcascade_frontalface_default.xml")
    return path if os.path.isfile(path) else None


def face_detector():
    if not hasattr(cv2, "CascadeClassifier") or _cascade_path() is None:
        raise ServiceError("face detection is unavailable: this OpenCV build has no Haar cascades", ErrorCode.UNAVAILABLE)
    if not hasattr(_local, "face"):
        _local.face = cv2.CascadeClassifier(_cascade_path())
    return _local.face


def people_detector():
    if not hasattr(cv2, "HOGDescriptor"):
        raise ServiceError("human detection is unavailable: this OpenCV build has no HOG detector", ErrorCode.UNAVAILABLE)
    if not hasattr(_local, "hog"):
        _local.hog = cv2.HOGDescriptor()
        _local.hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())
    return _local.hog


def _boxes(rects) -> Detections:
    return Detections(boxes=[Box(x=int(x), y=int(y), width=int(w), height=int(h)) for x, y, w, h in rects])


def face_detection(req: FaceDetect, ctx: ServiceContext) -> Detections:
    gray = cv2.equalizeHist(decode_image(req.image_b64, gray=True))
    det = face_detector()
    return _boxes(det.detectMultiScale(gray, scaleFactor=1.1, minNeighbors=5, minSize=(24, 24)))


HOG_WINDOW = (64, 128)  # (w, h) of the default people detector
MIN_PERSON_SCORE = 0.2  # SVM margin below which a window is not reported


def pad_for_people(img: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Image with a replicated border: a quarter of its size, and at least the HOG window.
    Returns (padded image, left pad, top pad)."""
    h, w = img.shape[:2]
    px = max(w // 4, (HOG_WINDOW[0] - w + 1) // 2 + 8)
    py = max(h // 4, (HOG_WINDOW[1] - h + 1) // 2 + 8)
    return cv2.copyMakeBorder(img, py, py, px, px, cv2.BORDER_REPLICATE), px, py


def _clip(rect, dx: int, dy: int, w: int, h: int) -> tuple[int, int, int, int] | None:
    x0, y0 = max(0, int(rect[0]) - dx), max(0, int(rect[1]) - dy)
    x1, y1 = min(w, int(rect[0] + rect[2]) - dx), min(h, int(rect[1] + rect[3]) - dy)
    return (x0, y0, x1 - x0, y1 - y0) if x1 - x0 > 4 and y1 - y0 > 4 else None


def detect_people(img: np.ndarray, smooth: float = 0.0) -> list[tuple[float, tuple[int, int, int, int]]]:
    """People in a colour (or gray) uint8 image: (score, (x, y, w, h)) best first, boxes clipped to the
    image. `smooth` > 0: a Gaussian blur of that sigma (pixels) first, against a camera's sensor noise,
    which HOG otherwise takes for edges (doors, QR codes on plain walls become "people").
    Shared by the Platform's human_detection and the Core's person events (agents/core_events.py).
    CPU work (~0.1 s at 320x240): call it from a thread."""
    if smooth > 0:
        img = cv2.GaussianBlur(img, (0, 0), smooth)
    h, w = img.shape[:2]
    padded, dx, dy = pad_for_people(img)
    rects, scores = people_detector().detectMultiScale(padded, winStride=(4, 4), padding=(8, 8), scale=1.05)
    scores = np.asarray(scores, float).ravel()
    found = [(float(s), _clip(r, dx, dy, w, h)) for r, s in zip(rects, scores) if s >= MIN_PERSON_SCORE]
    return [(s, box) for s, box in sorted(found, key=lambda f: -f[0]) if box is not None]


def distinct_people(found: list[tuple[float, tuple[int, int, int, int]]], overlap: float = 0.5) -> list:
    """`found` (best first) without a box that shares more than `overlap` of the smaller one's area
    with a better box: HOG also reports a person's legs or upper body on their own."""
    kept: list[tuple[float, tuple[int, int, int, int]]] = []
    for score, (x, y, w, h) in found:
        if all(max(0, min(x + w, kx + kw) - max(x, kx)) * max(0, min(y + h, ky + kh) - max(y, ky))
               <= overlap * min(w * h, kw * kh) for _, (kx, ky, kw, kh) in kept):
            kept.append((score, (x, y, w, h)))
    return kept


def human_detection(req: HumanDetect, ctx: ServiceContext) -> Detections:
    return _boxes([box for _, box in detect_people(decode_image(req.image_b64))])


class ObjectModels:
    """Per-user learned objects: name -> (keypoint coordinates, ORB descriptors, model image size);
    kept in `saved` (agents/services/saved.py) if given."""

    KIND = "object"

    def __init__(self, saved=None) -> None:
        self.lock = threading.Lock()
        self.models: dict[str, dict[str, tuple[np.ndarray, np.ndarray, tuple[int, int]]]] = {}
        self._saved = saved
        for rec in saved.records(self.KIND) if saved is not None else ():
            arrays = unpack_arrays(rec.blob)
            self.models.setdefault(rec.user, {})[rec.key] = (arrays["points"], arrays["descriptors"],
                                                            tuple(rec.meta["size"]))

    def put(self, user: str, name: str, pts: np.ndarray, desc: np.ndarray, size: tuple[int, int]) -> None:
        if self._saved is not None:
            self._saved.put(self.KIND, user, name, {"size": [int(v) for v in size]},
                            pack_arrays(points=pts, descriptors=desc))
        with self.lock:
            self.models.setdefault(user, {})[name] = (pts, desc, size)

    def clear(self, user: str) -> None:
        if self._saved is not None:
            self._saved.delete(self.KIND, user)
        with self.lock:
            self.models.pop(user, None)


def models(ctx: ServiceContext) -> ObjectModels:
    return ctx.state.store("objects", lambda: ObjectModels(ctx.state.saved))


def orb_features(gray: np.ndarray, n: int = 1500):
    kps, desc = cv2.ORB_create(nfeatures=n).detectAndCompute(gray, None)
    return np.float32([k.pt for k in kps]), desc


def learn_object(req: LearnObject, ctx: ServiceContext) -> Done:
    gray = decode_image(req.image_b64, gray=True)
    pts, desc = orb_features(gray, 1000)
    if desc is None or len(pts) < 10:
        raise ServiceError("the object image has too little texture to learn (fewer than 10 features)", ErrorCode.NO_FEATURES)
    models(ctx).put(ctx.user, req.name, pts, desc, gray.shape[::-1])
    return Done()


def find_objects(req: FindObjects, ctx: ServiceContext) -> FoundObjects:
    gray = decode_image(req.image_b64, gray=True)
    store = models(ctx)
    with store.lock:
        learned = dict(store.models.get(ctx.user, {}))
    if not learned:
        raise ServiceError("no objects learned yet for this user", ErrorCode.NO_MODELS)
    pts, desc = orb_features(gray)
    found = []
    if desc is not None and len(pts) >= 4:
        matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        for name, (mpts, mdesc, (w, h)) in learned.items():
            pairs = matcher.knnMatch(mdesc, desc, k=2)
            good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.75 * p[1].distance]
            if len(good) < req.min_matches:
                continue
            src = mpts[[m.queryIdx for m in good]].reshape(-1, 1, 2)
            dst = pts[[m.trainIdx for m in good]].reshape(-1, 1, 2)
            H, inliers = cv2.findHomography(src, dst, cv2.RANSAC, 5.0)
            if H is None or int(inliers.sum()) < req.min_matches:
                continue
            outline = cv2.perspectiveTransform(np.float32([[0, 0], [w, 0], [w, h], [0, h]]).reshape(-1, 1, 2), H)
            found.append(FoundObject(name=name, matches=int(inliers.sum()), corners=outline.reshape(4, 2).tolist()))
    found.sort(key=lambda f: -f.matches)
    return FoundObjects(objects=found[:req.limit])


def clear_objects(req: ClearObjects, ctx: ServiceContext) -> Done:
    models(ctx).clear(ctx.user)
    return Done()
