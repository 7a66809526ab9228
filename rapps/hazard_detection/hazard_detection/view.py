"""Where to stand and where to look to check a door (issue 42 item 3), from the doorway's geometry, the
home's rooms and the robot's own camera, before the robot goes there (run on the Cloud Agent).

The original image-only door check (agents/services/hazard.py) looks at where the door meets the floor
(the hinge: the centre of the image) and compares the best-scoring near-horizontal line (within 30 deg)
of the left half with that of the right half: the wall's floor line in one, the leaf's in the other.
Which lines it takes depends on where the camera stands:

- a floor direction at angle phi from the image's horizontal appears at atan(sin(beta) tan(phi)), beta
  the camera's depression: seen from straight in front a wide-open leaf is steep in the image, its half
  keeps no usable line, and the method takes whatever level line is left there (the floor line of the
  far wall of the room beyond: an open door read as closed);
- seen diagonally (the wall at about -45 deg, the wide-open leaf at +45 deg) the whole swing stays a
  usable line when beta is low enough for the camera's height;
- the wall beyond the latch continues a closed door's line and must not win the leaf's half.

`view_margin` emulates the method on a pinhole model of the robot's camera at a stand facing the hinge:
the floor lines of the walls of the rooms on both sides of the door (cut at doorways, seen only where no
wall or the leaf is in between) and the leaf's at each opening of ANGLES_DEG, each half's best line by
the original's own score (rapps.sdk.vision.floor_line_score), the reading and the decision, with margins
for a stand reached a few centimetres off. `door_views` ranks stands round the hinge by that margin.
What the model does not know (furniture, people, a rug) the check's confidence tells: a frame whose lines
do not pass where the camera looks is not used, and the robot moves to the next view."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rapps.sdk import vision

FLOOR_LINE_DEG = math.degrees(vision.FLOOR_LINE_RAD)
WALL_T = 0.10  # wall thickness the door frame is cut into (m)
ANGLES_DEG = (0.0, 20.0, 30.0, 45.0, 60.0, 75.0, 90.0)  # leaf openings the view must decide right
ANGLE_MARGIN_DEG = 4.0  # a line this near the 30 deg bound may cross it a few cm off the stand
SPLIT_MARGIN_DEG = 3.0  # an open leaf reads above the threshold by this much at least
SCORE_MARGIN = 1.25  # the right line of a half must outscore a wrong one by this factor
NO_LINE_MARGIN_DEG = 1.0  # an open leaf's half without any floor line: right, but barely
SAMPLE_M = 0.04  # floor lines are sampled this finely for what the camera sees of them


@dataclass(frozen=True)
class CameraModel:
    """The robot's camera as the view model needs it: pinhole intrinsics at the check's resolution, its
    height above the floor and how far ahead of the base's centre it sits (facing where it looks)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    z: float
    ahead: float = 0.0


@dataclass(frozen=True)
class DoorView:
    """A stand (facing the hinge) and where to look; `margin`: the worst predicted margin of the image
    method over the leaf's openings (degrees; higher is safer)."""

    x: float
    y: float
    theta: float
    look: tuple[float, float, float]
    margin: float
    distance_m: float  # from the hinge
    bearing_deg: float  # from the closed leaf's direction towards the robot's side


def door_axes(door, robot_xy) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(hinge, c: hinge -> latch, s: unit normal towards the robot's side, swing: +1 when the leaf
    opens towards the robot's side, -1 away from it). Without `opens` the leaf is taken to swing away."""
    h = np.asarray(door.hinge, float)
    yaw = math.radians(door.closed_yaw_deg)
    c = np.array([math.cos(yaw), math.sin(yaw)])
    left = np.array([-c[1], c[0]])  # where a leaf opening "left" (counter-clockwise) goes
    s = left if float(np.dot(np.asarray(robot_xy, float) - h, left)) >= 0 else -left
    opens = getattr(door, "opens", None)
    if opens is None:
        return h, c, s, -1
    n = left if opens == "left" else -left
    return h, c, s, 1 if float(np.dot(n, s)) > 0 else -1


def leaf_direction(c: np.ndarray, s: np.ndarray, swing: int, angle_deg: float) -> np.ndarray:
    a = math.radians(angle_deg)
    return math.cos(a) * c + math.sin(a) * (s * swing)


# ------------------------------------------------------------------------------ the home's walls
def wall_faces(rooms, doors) -> list[tuple[np.ndarray, np.ndarray]]:
    """The floor lines of the rooms' walls (each room's rectangle is its walls' inner faces), cut where
    a door's gap is (a doorway without a door is not known: taken for wall)."""
    gaps = []
    for d in doors:
        h = np.asarray(d.door.hinge, float)
        yaw = math.radians(d.door.closed_yaw_deg)
        gaps.append((h, h + d.door.width_m * np.array([math.cos(yaw), math.sin(yaw)])))
    out = []
    for r in rooms:
        x0, y0, x1, y1 = r.rect
        for a, b in (((x0, y0), (x1, y0)), ((x1, y0), (x1, y1)), ((x1, y1), (x0, y1)), ((x0, y1), (x0, y0))):
            out += _cut(np.asarray(a, float), np.asarray(b, float), gaps)
    return out


def _cut(a: np.ndarray, b: np.ndarray, gaps) -> list[tuple[np.ndarray, np.ndarray]]:
    """Segment a-b less the door gaps lying along it (within a wall's thickness)."""
    length = float(np.linalg.norm(b - a))
    u = (b - a) / length
    keep = [(0.0, length)]
    for g0, g1 in gaps:
        off = [abs(float(u[0] * (g - a)[1] - u[1] * (g - a)[0])) for g in (g0, g1)]
        if max(off) > WALL_T:
            continue
        lo, hi = sorted(float(np.dot(g - a, u)) for g in (g0, g1))
        keep = [piece for s, e in keep for piece in ((s, min(e, lo)), (max(s, hi), e)) if piece[1] - piece[0] > 1e-3]
    return [(a + s * u, a + e * u) for s, e in keep]


def _crosses(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether the segments p[i]-q (q: one point) properly cross a[j]-b[j]: bool (len(p), len(a))."""
    def orient(o, x, y):
        return (x[..., 0] - o[..., 0]) * (y[..., 1] - o[..., 1]) - (x[..., 1] - o[..., 1]) * (y[..., 0] - o[..., 0])
    P, Q = p[:, None, :], np.broadcast_to(q, p.shape)[:, None, :]
    A, B = a[None, :, :], b[None, :, :]
    d1, d2 = orient(A, B, P), orient(A, B, Q)
    d3, d4 = orient(P, Q, A), orient(P, Q, B)
    return (d1 * d2 < -1e-12) & (d3 * d4 < -1e-12)


# ------------------------------------------------------------------------------ the camera
def _frame(cam: np.ndarray, look: np.ndarray) -> np.ndarray:
    """Rows: right, down, forward (optical axis) of a camera at `cam` looking at `look`, no roll."""
    z = look - cam
    z /= np.linalg.norm(z)
    right = np.cross(z, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(z, right), z])


def _project(camera: CameraModel, R: np.ndarray, cam: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (n, 2) of floor points and whether each is in front of the camera and inside the image."""
    q = (np.c_[xy, np.zeros(len(xy))] - cam) @ R.T
    front = q[:, 2] > 0.05
    z = np.where(front, q[:, 2], 1.0)
    uv = np.c_[camera.cx + camera.fx * q[:, 0] / z, camera.cy + camera.fy * q[:, 1] / z]
    inside = front & (uv[:, 0] >= 0) & (uv[:, 0] <= camera.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= camera.height - 1)
    return uv, inside


def _pieces(uv: np.ndarray, ok: np.ndarray, min_px: float) -> list[tuple[float, float, float, float]]:
    """Image segments of the runs of consecutive usable samples of one floor line, long enough."""
    edges = np.diff(np.r_[0, ok.astype(np.int8), 0])
    out = []
    for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1):
        seg = (*uv[start], *uv[stop])
        if stop > start and math.hypot(seg[2] - seg[0], seg[3] - seg[1]) >= min_px:
            out.append(tuple(float(v) for v in seg))
    return out


def _angle(seg) -> float:
    dx, dy = seg[2] - seg[0], seg[3] - seg[1]
    return 90.0 if dx == 0 else math.degrees(math.atan(dy / dx))


class _Scene:
    """One stand: the camera, and what it sees of the home's walls (without the leaf)."""

    def __init__(self, camera: CameraModel, stand, h, faces, occluders):
        p = np.asarray(stand, float)
        heading = (h - p) / np.linalg.norm(h - p)
        self.camera = camera
        self.eye = p + camera.ahead * heading
        self.cam = np.r_[self.eye, camera.z]
        self.R = _frame(self.cam, np.r_[h, 0.0])
        self.min_px = vision.DoorLineParams().hough_len * camera.width / vision.DoorLineParams().width
        self.lines = self._lines(faces, occluders)  # per wall face: (samples xy, pixels, seen without the leaf)

    def _lines(self, faces, occluders) -> list[tuple]:
        oa, ob = (np.array([o[k] for o in occluders]) for k in (0, 1))
        out = []
        for a, b in faces:
            n = max(2, int(np.linalg.norm(b - a) / SAMPLE_M) + 1)
            xy = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
            uv, inside = _project(self.camera, self.R, self.cam, xy)
            if inside.any():
                out.append((xy, uv, inside & ~_crosses(xy, self.eye, oa, ob).any(axis=1)))
        return out

    def with_box(self, box, occluders) -> "_Scene":
        """The same stand with a piece of furniture more (its floor lines, hiding what is behind it)."""
        other = object.__new__(_Scene)
        other.__dict__.update(self.__dict__)
        ba, bb = (np.array([o[k] for o in box]) for k in (0, 1))
        other.lines = [(xy, uv, seen & ~_crosses(xy, self.eye, ba, bb).any(axis=1)) for xy, uv, seen in self.lines]
        other.lines += self._lines(box, occluders + box)
        return other

    def segments(self, leaf: tuple[np.ndarray, np.ndarray] | None) -> list[tuple]:
        """Image segments of the walls' floor lines not hidden by the leaf (a-b), and the leaf's own."""
        out = []
        for xy, uv, seen in self.lines:
            ok = seen if leaf is None else seen & ~_crosses(xy, self.eye, leaf[0][None], leaf[1][None])[:, 0]
            out += _pieces(uv, ok, self.min_px)
        if leaf is not None:
            xy = leaf[0] + np.linspace(0.0, 1.0, 30)[:, None] * (leaf[1] - leaf[0])
            uv, inside = _project(self.camera, self.R, self.cam, xy)
            out += [seg + ("leaf",) for seg in _pieces(uv, inside, self.min_px)]
        return out


def _best(segs, width: int, side: str, bound: float):
    """The method's line of one half among segments within `bound` deg of horizontal, with its score."""
    best, top = None, 0.0
    for seg in segs:
        if abs(_angle(seg)) < bound:
            score = vision.floor_line_score(seg[:4], width, side)
            if score > top:
                best, top = seg, score
    return best, top


def _reading(segs, width: int, bound: float) -> tuple[float | None, dict]:
    lines = {side: _best(segs, width, side, bound) for side in ("left", "right")}
    if any(seg is None for seg, _ in lines.values()):
        return None, lines  # 90: a half without a floor line
    return abs(_angle(lines["left"][0]) - _angle(lines["right"][0])), lines


CLUTTER_GAP_M, CLUTTER_DEPTH_M, CLUTTER_LENGTH_M = 0.5, 0.4, 1.0


def clutter(door, robot_side_xy) -> list[list[tuple[np.ndarray, np.ndarray]]]:
    """The furniture the map may have and the home description does not say: a cabinet against the
    door's wall beside the hinge, or beside the latch (CLUTTER_GAP_M from the gap, CLUTTER_DEPTH_M
    deep, CLUTTER_LENGTH_M long), each as its floor lines facing the robot's side."""
    h, c, s, _ = door_axes(door, robot_side_xy)
    face = h + s * (WALL_T / 2)
    out = []
    for start, along in ((face - CLUTTER_GAP_M * c, -c), (face + (door.width_m + CLUTTER_GAP_M) * c, c)):
        end = start + CLUTTER_LENGTH_M * along
        out.append([(start + CLUTTER_DEPTH_M * s, end + CLUTTER_DEPTH_M * s),  # its front
                    (start, start + CLUTTER_DEPTH_M * s)])  # its side towards the door
    return out


def view_margin(camera: CameraModel, door, stand, robot_side_xy, faces, occluders,
                open_threshold_deg: float = 5.0, robust: bool = True) -> float:
    """`view_margin_in` for the home as described and, with `robust`, with a cabinet beside the hinge
    or beside the latch (`clutter`): the worst of the three."""
    h = door_axes(door, robot_side_xy)[0]
    scene = _Scene(camera, stand, h, faces, occluders)
    worst = view_margin_in(scene, door, robot_side_xy, open_threshold_deg)
    if robust:
        for box in clutter(door, robot_side_xy):
            if worst < 0:
                break  # ranked below every sound view anyway
            worst = min(worst, view_margin_in(scene.with_box(box, occluders), door, robot_side_xy, open_threshold_deg))
    return worst


def view_margin_in(scene: "_Scene", door, robot_side_xy, open_threshold_deg: float = 5.0) -> float:
    """The worst predicted margin (deg) of the image method from `stand` (facing the hinge) over
    ANGLES_DEG; negative: it would decide wrong somewhere. Each opening is read twice, with the 30 deg
    bound ANGLE_MARGIN_DEG tighter and looser (a stand reached a few cm off); per opening the margin
    is the reading's distance from the threshold (an open door: above it by SPLIT_MARGIN_DEG; 90 deg,
    no line at all, counts as NO_LINE_MARGIN_DEG), and the right line must outscore a wrong one in its half by SCORE_MARGIN."""
    h, c, s, swing = door_axes(door, robot_side_xy)
    width, w = scene.camera.width, float(door.width_m)
    worst = math.inf
    for a in ANGLES_DEG:
        d = leaf_direction(c, s, swing, a)
        leaf = (h + 0.02 * d, h + (w - 0.02) * d)
        segs = scene.segments(leaf)
        if not any(len(seg) == 5 for seg in segs):
            return -math.inf  # the leaf is out of view
        for bound in (FLOOR_LINE_DEG - ANGLE_MARGIN_DEG, FLOOR_LINE_DEG + ANGLE_MARGIN_DEG):
            reading, lines = _reading(segs, width, bound)
            if a == 0.0:
                margin = open_threshold_deg - (90.0 if reading is None else reading)
            elif reading is None:  # 90, right, but with no line to show it: any line the model does not
                margin = NO_LINE_MARGIN_DEG  # know of (furniture, a rug) would be taken instead
            else:
                margin = reading - open_threshold_deg - SPLIT_MARGIN_DEG
                if not any(seg is not None and len(seg) == 5 for seg, _ in lines.values()):
                    margin = min(margin, NO_LINE_MARGIN_DEG)  # right by another line's angle: by chance
            worst = min(worst, margin, _score_margin(segs, lines, width, bound, a))
    return worst


def _score_margin(segs, lines, width: int, bound: float, angle: float) -> float:
    """In the leaf's half: when an open leaf's line is chosen, how far it outscores the best line that
    would read closed (0 deg margin at SCORE_MARGIN); when a wrong line is chosen, nothing to add (the
    reading says it)."""
    if angle == 0.0:
        return math.inf
    for side, (seg, score) in lines.items():
        if seg is None or len(seg) != 5:
            continue
        rivals = [vision.floor_line_score(o[:4], width, side) for o in segs
                  if len(o) == 4 and abs(_angle(o)) < bound]
        rival = max(rivals, default=0.0)
        return 10.0 * (score / SCORE_MARGIN - rival) / max(score, 1e-9)
    return math.inf


def door_views(door, robot_side_xy, camera: CameraModel, rooms=(), doors=(), robot_radius: float = 0.35,
               room_rect=None, distances=(0.8, 1.0, 1.25, 1.5, 1.8, 2.1, 2.5),
               bearings_deg=tuple(range(15, 170, 12)), open_threshold_deg: float = 5.0) -> list[DoorView]:
    """Stands round the hinge on the robot's side (the side of `robot_side_xy`), best first: inside
    `room_rect` (the room the robot checks from, when known) and clear of the wall and of the leaf's
    sweep by the robot's radius; every stand the model rates, even negative margins (a home the model
    cannot be sure of still gets its best try)."""
    h, c, s, swing = door_axes(door, robot_side_xy)
    faces = wall_faces(rooms, doors)
    occluders = [f for f in faces]
    w = float(door.width_m)
    out = []
    for dist in distances:
        for bearing in bearings_deg:
            b = math.radians(bearing)
            p = h + dist * (math.cos(b) * c + math.sin(b) * s)
            if float(np.dot(p - h, s)) < robot_radius + WALL_T / 2 + 0.05:
                continue  # too near the wall
            if room_rect is not None and not _inside(p, room_rect, robot_radius + 0.05):
                continue
            if swing > 0 and _leaf_sweep_distance(p, h, c, s, w) < robot_radius + 0.10:
                continue  # the leaf swings towards this side: not where it would hit the robot
            margin = view_margin(camera, door, p, robot_side_xy, faces, occluders, open_threshold_deg)
            if margin == -math.inf:
                continue
            out.append(DoorView(float(p[0]), float(p[1]), math.atan2(h[1] - p[1], h[0] - p[0]),
                                (float(h[0]), float(h[1]), 0.0), float(margin), float(dist), float(bearing)))
    out.sort(key=lambda v: (-min(v.margin, 6.0), v.distance_m))  # safe enough, then near the door
    return out


def distinct(views: list[DoorView], apart_m: float = 0.4) -> list[DoorView]:
    """The views in order, each at least `apart_m` from those before it: a second look is from
    elsewhere, not from the cell next door."""
    out: list[DoorView] = []
    for v in views:
        if all(math.hypot(v.x - o.x, v.y - o.y) >= apart_m for o in out):
            out.append(v)
    return out


def _inside(p: np.ndarray, rect, inset: float) -> bool:
    return rect[0] + inset <= p[0] <= rect[2] - inset and rect[1] + inset <= p[1] <= rect[3] - inset


def _leaf_sweep_distance(p, h, c, s, width: float) -> float:
    """Distance from p to the quarter disc a leaf opening towards s sweeps."""
    v = p - h
    if float(np.dot(v, c)) >= 0 and float(np.dot(v, s)) >= 0:  # within the quarter's angles
        return max(0.0, float(np.linalg.norm(v)) - width)
    return min(_segment_distance(p, h, h + width * e) for e in (c, s))


def _segment_distance(p, a, b) -> float:
    d = b - a
    t = float(np.clip(np.dot(p - a, d) / max(float(np.dot(d, d)), 1e-12), 0.0, 1.0))
    return float(np.linalg.norm(p - (a + t * d)))


def predicted_readings(camera: CameraModel, door, stand, robot_side_xy, rooms=(), doors=()) -> list:
    """The image method's predicted reading (deg, None for 90) at each of ANGLES_DEG (validation)."""
    h, c, s, swing = door_axes(door, robot_side_xy)
    faces = wall_faces(rooms, doors)
    scene = _Scene(camera, stand, h, faces, faces)
    out = []
    for a in ANGLES_DEG:
        d = leaf_direction(c, s, swing, a)
        reading, _ = _reading(scene.segments((h + 0.02 * d, h + (door.width_m - 0.02) * d)), camera.width,
                              FLOOR_LINE_DEG)
        out.append(None if reading is None else round(reading, 1))
    return out
