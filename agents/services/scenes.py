"""Scene recognition (paper 000 sec. 5.3): which room of the user's home a camera image was taken in.

A home's rooms are learned from views taken in them (`scene_recognition_learn`: a robot touring the home
with its owner, or a RApp that knows where it stands from its localization, sends each image with its
room), and a new view is named after the room of its nearest learned view. No generic model of "a
kitchen" is used: a room is recognised as the room of this home it looks like.

The descriptor (about 1 ms a view) is made for what tells rooms apart in a home, their furniture and
its colours: a hue-saturation-value histogram (8 x 3 x 3 bins) in each cell of a 2 x 2 grid, a global
one, and a 3 x 3 grid of gradient-orientation histograms (8 bins, as GIST or HOG do) for the shapes;
each part square-rooted (Hellinger) and weighted to unit length together. Views are compared by their
Euclidean distance (0 equal, 2 at most). A view no nearer than `max_distance` to any learned one is
answered with no room (a bare wall, a corridor the home description gives no room for).

Per user and home, views are kept in the Platform's saved data (kind "scene", one record per room with
its descriptors; agents/services/saved.py). Measured accuracy on the houses: docs/scene-recognition.md.
"""
from __future__ import annotations

import threading
from typing import NamedTuple

import cv2
import numpy as np

from ontology.errors import ErrorCode
from ontology.registry import Done
from ontology.services.vision import ForgetScenes, LearnScene, RecognizeScene, SceneGuess, SceneReply

from .context import ServiceContext
from .errors import ServiceError
from .images import decode_image
from .saved import pack_arrays, unpack_arrays

SIZE = (96, 72)  # the view is scaled to this before anything is counted
HSV_BINS = (8, 3, 3)
MAX_VIEWS_PER_ROOM = 200


def _hsv_hist(hsv: np.ndarray) -> np.ndarray:
    h = cv2.calcHist([hsv], [0, 1, 2], None, list(HSV_BINS), [0, 180, 0, 256, 0, 256]).ravel()
    return h / max(h.sum(), 1.0)


def _orientations(gray: np.ndarray, grid: int = 3, bins: int = 8) -> np.ndarray:
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1)
    mag, ang = cv2.cartToPolar(gx, gy)
    index = np.minimum((ang % np.pi) / np.pi * bins, bins - 1).astype(int)  # unsigned orientation
    out = []
    h, w = gray.shape
    for i in range(grid):
        for j in range(grid):
            cell = (slice(i * h // grid, (i + 1) * h // grid), slice(j * w // grid, (j + 1) * w // grid))
            hist = np.bincount(index[cell].ravel(), weights=mag[cell].ravel(), minlength=bins)
            out.append(hist / max(hist.sum(), 1e-6))
    return np.concatenate(out)


def scene_descriptor(img_bgr: np.ndarray) -> np.ndarray:
    """A unit-length float32 vector describing a view (see the module docstring)."""
    small = cv2.resize(img_bgr if img_bgr.ndim == 3 else cv2.cvtColor(img_bgr, cv2.COLOR_GRAY2BGR), SIZE,
                       interpolation=cv2.INTER_AREA)
    hsv = cv2.cvtColor(small, cv2.COLOR_BGR2HSV)
    h, w = hsv.shape[:2]
    parts = [np.sqrt(_hsv_hist(hsv))]
    for i in range(2):
        for j in range(2):
            parts.append(np.sqrt(_hsv_hist(np.ascontiguousarray(hsv[i * h // 2:(i + 1) * h // 2,
                                                                    j * w // 2:(j + 1) * w // 2]))))
    parts.append(np.sqrt(_orientations(cv2.cvtColor(small, cv2.COLOR_BGR2GRAY).astype(np.float32))))
    # each part has unit length after the square root (its histogram sums to 1): weigh colour and shape
    colour = np.concatenate(parts[:5]) / np.sqrt(5)
    shape = parts[5] / np.sqrt(9)
    v = np.concatenate([colour, shape]).astype(np.float32)
    return v / np.linalg.norm(v)


ORB_PER_VIEW = 300
MAX_ORB_PER_ROOM = 6000
MIN_VOTES = 12  # feature matches (summed over a look-around) that name a room on their own


def orb_descriptors(img_bgr: np.ndarray) -> np.ndarray:
    """Up to ORB_PER_VIEW binary descriptors [n, 32] of the view (QR panels, furniture edges, doors)."""
    gray = img_bgr if img_bgr.ndim == 2 else cv2.cvtColor(img_bgr, cv2.COLOR_BGR2GRAY)
    _, desc = cv2.ORB_create(nfeatures=ORB_PER_VIEW).detectAndCompute(gray, None)
    return desc if desc is not None else np.zeros((0, 32), np.uint8)


class RoomViews(NamedTuple):
    glob: np.ndarray  # [n, d] float32: one descriptor per learned view
    orb: np.ndarray  # [m, 32] uint8: the views' feature descriptors, stacked


class SceneViews:
    """Per (user, home): room -> RoomViews; kept in `saved` if given."""

    KIND = "scene"

    def __init__(self, saved=None) -> None:
        self.lock = threading.Lock()
        self.rooms: dict[tuple[str, str], dict[str, RoomViews]] = {}
        self._saved = saved
        for rec in saved.records(self.KIND) if saved is not None else ():
            arrays = unpack_arrays(rec.blob)
            self.rooms.setdefault((rec.user, rec.meta["home"]), {})[rec.meta["room"]] = RoomViews(arrays["glob"],
                                                                                                   arrays["orb"])

    def of(self, user: str, home: str) -> dict[str, RoomViews]:
        with self.lock:
            return dict(self.rooms.get((user, home), {}))

    def add(self, user: str, home: str, room: str, glob: np.ndarray, orb: np.ndarray) -> int:
        with self.lock:
            views = self.rooms.setdefault((user, home), {})
            old = views.get(room) or RoomViews(np.zeros((0, len(glob)), np.float32), np.zeros((0, 32), np.uint8))
            kept = views[room] = RoomViews(np.vstack([old.glob, glob[None]])[-MAX_VIEWS_PER_ROOM:],
                                           np.vstack([old.orb, orb])[-MAX_ORB_PER_ROOM:])
        if self._saved is not None:
            self._saved.put(self.KIND, user, f"{home}\x00{room}", {"home": home, "room": room, "views": len(kept.glob)},
                            pack_arrays(glob=kept.glob, orb=kept.orb))
        return len(kept.glob)

    def forget(self, user: str, home: str, room: str = "") -> None:
        with self.lock:
            views = self.rooms.get((user, home), {})
            rooms = [room] if room else list(views)
            for r in rooms:
                views.pop(r, None)
        if self._saved is not None:
            for r in rooms:
                self._saved.delete(self.KIND, user, f"{home}\x00{r}")


def views(ctx: ServiceContext) -> SceneViews:
    return ctx.state.store("scenes", lambda: SceneViews(ctx.state.saved))


def _images(req) -> list[np.ndarray]:
    return [decode_image(b64, f"images_b64[{i}]") for i, b64 in enumerate(req.images_b64)]


def learn_scene(req: LearnScene, ctx: ServiceContext) -> Done:
    for img in _images(req):
        views(ctx).add(ctx.user, req.home_id, req.room, scene_descriptor(img), orb_descriptors(img))
    return Done()


def votes(room_orb: np.ndarray, query: np.ndarray) -> int:
    """Query features whose best match among the room's is clearly better than the second (ratio test)."""
    if len(room_orb) < 2 or len(query) == 0:
        return 0
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(query, room_orb, k=2)
    return sum(1 for m in pairs if len(m) == 2 and m[0].distance < 64 and m[0].distance < 0.75 * m[1].distance)


def rank_rooms(known: dict[str, RoomViews], images: list[np.ndarray]) -> list[SceneGuess]:
    """Every room with its feature votes (summed over the images) and the mean over the images of the
    distance to its nearest view; most votes first, then nearest."""
    globs = [scene_descriptor(img) for img in images]
    orbs = [orb_descriptors(img) for img in images]
    out = []
    for room, v in known.items():
        dist = float(np.mean([np.min(np.linalg.norm(v.glob - g, axis=1)) for g in globs]))
        out.append(SceneGuess(room=room, distance=round(dist, 4), votes=sum(votes(v.orb, o) for o in orbs)))
    return sorted(out, key=lambda g: (-g.votes if g.votes >= MIN_VOTES else 0, g.distance))


def recognize_scene(req: RecognizeScene, ctx: ServiceContext) -> SceneReply:
    known = views(ctx).of(ctx.user, req.home_id)
    if not known:
        raise ServiceError(f"no rooms learned yet for home {req.home_id!r} of this user (scene_recognition_learn)",
                           ErrorCode.NO_MODELS)
    ranked = rank_rooms(known, _images(req))
    best = ranked[0]
    sure = best.votes >= MIN_VOTES or best.distance <= req.max_distance
    return SceneReply(room=best.room if sure else "", distance=best.distance, votes=best.votes, candidates=ranked)


def forget_scenes(req: ForgetScenes, ctx: ServiceContext) -> Done:
    views(ctx).forget(ctx.user, req.home_id, req.room)
    return Done()
