"""Generated houses: a seed -> the same house description dict robots/floorplan.py reads from YAML.

    desc = generate(5)                         # deterministic per seed
    plan = load_plan(desc, seed=5)             # or World.from_file("generated", seed=5)
    python -m robots.house_gen 5 > house5.yaml

A rectangle split into 3-8 rooms (3 m or more a side); a random spanning tree of the rooms that
share a wall decides the connections: between rooms the robot walks through an open doorway or a
passage door (the owner leaves it open; 1.0 m), into dead-end rooms a door that is a hazard to check
from the robot's side (0.9-1.0 m, swinging into the dead-end room). Floor lamps stand in corners of
the rooms the robot walks through, furniture against the walls (and a table in big rooms), only
where the robot keeps a way through (checked on an inflated occupancy grid).

QR landmarks follow an installer's rule, the one the hand-made house uses: a 0.35 m code (1280x960
localization decodes it to ~5 m) with its centre 0.7 m high (the height the hazard RApp tilts its
head to), on every wall of every room, first and last 0.6 m from the corners, at most 2 m apart;
a spot behind furniture, in a door gap, beside a hinge or near a lamp is moved up to 0.6 m along the
wall (not nearer than 0.45 m to a corner), else left out.

The description's `hazards` section (read by scenarios/home_setup.py, as its LAYOUTS for the
hand-made houses) lists the doors to check and from which side, the lamps with the direction into
the room, and the passage doors. Door angles and lamp states are not drawn here: the scenario's
overrides draw them from the same seed.
"""
from __future__ import annotations

import copy
import functools
import math
import sys
import zlib
from dataclasses import dataclass, field

import numpy as np
import yaml
from scipy import ndimage

from ontology.robot_types import ROBOT_TYPES, widest_clearance_m

from .floorplan import Door, Lamp, load_plan
from .gridmap import FREE, build_grid_map

GENERATED = "generated"  # the house name that World.from_file and the scenarios take for these houses
WALL_T, WALL_H = 0.1, 2.5
ROOM_MIN = 3.0  # m, shortest room side
JUNCTION_CLEAR = 0.55  # m from a wall junction to a door gap: a perpendicular wall's foot near the
#                        hinge would read as an open leaf to the door check
PASSAGE_W, OPENING_W, HAZARD_W = 1.0, (1.0, 1.4), (0.9, 1.0)
PASSAGE_OPEN_DEG = (80.0, 90.0)  # how far the owner leaves a passage door open (scenario overrides)
LAMP_INSET, LAMP_Z, LAMP_STAND_M = 0.4, 1.4, 1.4
# the passage every generated house leaves: the widest robot type's clearance radius (ontology/robot_types.py)
NAV_RADIUS = widest_clearance_m()
START_CLEARANCE = 0.7  # m from any obstacle for a robot's start pose
QR_SIZE, QR_Z, QR_SPACING, QR_END, QR_SHIFTS = 0.35, 0.7, 2.0, 0.6, (0.0, 0.3, -0.3, 0.6, -0.6)
QR_CORNER = 0.45  # m: no spot nearer a corner (the panel is ~0.45 m wide)
GRID_RES = 0.05
ROOM_NAMES = ["living", "hall", "kitchen", "bedroom", "office", "study", "bathroom", "pantry"]
# name: (length along the wall, depth, height, colour)
WALL_ITEMS = {
    "sofa": (2.0, 0.9, 0.8, (0.3, 0.35, 0.55)), "tv_stand": (1.6, 0.5, 0.6, (0.2, 0.2, 0.2)),
    "shelf": (1.6, 0.4, 1.8, (0.45, 0.3, 0.2)), "armchair": (0.9, 0.9, 0.9, (0.5, 0.3, 0.3)),
    "counter": (2.4, 0.6, 0.9, (0.7, 0.7, 0.72)), "fridge": (0.7, 0.7, 1.8, (0.9, 0.9, 0.95)),
    "bed": (1.6, 2.0, 0.5, (0.6, 0.3, 0.3)), "wardrobe": (1.4, 0.6, 2.0, (0.45, 0.3, 0.2)),
    "nightstand": (0.5, 0.4, 0.55, (0.55, 0.4, 0.25)), "desk": (1.4, 0.7, 0.75, (0.55, 0.4, 0.25)),
    "cabinet": (1.0, 0.5, 1.2, (0.5, 0.45, 0.4)), "bench": (1.2, 0.4, 0.45, (0.45, 0.3, 0.2)),
    "shoe_cabinet": (0.9, 0.35, 1.0, (0.6, 0.55, 0.5)), "bathtub": (1.7, 0.8, 0.6, (0.92, 0.92, 0.95)),
    "washer": (0.6, 0.6, 0.85, (0.9, 0.9, 0.9)),
}
CENTRE_ITEMS = {"coffee_table": (1.0, 0.6, 0.45, (0.55, 0.4, 0.25)),
                "dining_table": (1.4, 0.9, 0.75, (0.55, 0.4, 0.25))}
ROOM_FURNITURE = {
    "living": ["sofa", "tv_stand", "shelf", "armchair"], "hall": ["bench", "shoe_cabinet", "cabinet"],
    "kitchen": ["counter", "fridge", "cabinet"], "bedroom": ["bed", "wardrobe", "nightstand"],
    "office": ["desk", "shelf", "cabinet"], "study": ["desk", "shelf", "armchair"],
    "bathroom": ["bathtub", "washer", "cabinet"], "pantry": ["shelf", "cabinet"],
}


@dataclass
class Room:
    name: str
    rect: tuple[float, float, float, float]  # wall centre lines x0, y0, x1, y1
    walk: bool = True  # the robot walks through it (False: a dead-end room behind a hazard door)


@dataclass
class Link:
    """A connection of two rooms through the wall line between them: 'opening', 'passage' or 'hazard'."""

    kind: str
    a: int
    b: int
    axis: str  # "x": a vertical wall x = at; "y": a horizontal wall y = at
    at: float
    lo: float  # gap from lo to lo + width along the wall
    width: float
    door: dict | None = None

    def gap(self) -> tuple[tuple[float, float], tuple[float, float]]:
        if self.axis == "x":
            return (self.at, self.lo), (self.at, self.lo + self.width)
        return (self.lo, self.at), (self.lo + self.width, self.at)

    def centre(self) -> np.ndarray:
        (x0, y0), (x1, y1) = self.gap()
        return np.array([(x0 + x1) / 2, (y0 + y1) / 2])


@dataclass
class Draft:
    rng: np.random.Generator
    rooms: list[Room]
    walls: list[list[float]]
    links: list[Link] = field(default_factory=list)
    lamps: list[dict] = field(default_factory=list)
    lamp_dirs: dict[str, list[float]] = field(default_factory=dict)
    furniture: list[dict] = field(default_factory=list)
    keep_out: list[tuple[np.ndarray, float]] = field(default_factory=list)  # discs no furniture may touch


def _r(v: float) -> float:
    return round(float(v), 3)


# ---------------------------------------------------------------- rooms and walls

def split_rooms(rng: np.random.Generator, n: int) -> tuple[list[tuple], list[list[float]]] | None:
    """Split a footprint of about n * 14..24 m2 into n rooms (binary splits of the biggest room along
    its longer side); None when the footprint cannot take n rooms of ROOM_MIN a side."""
    area = n * rng.uniform(14.0, 24.0)
    aspect = rng.uniform(0.7, 1.4)
    w = round(math.sqrt(area * aspect), 1)
    h = round(area / w, 1)
    rects = [(0.0, 0.0, w, h)]
    walls = [[0, 0, w, 0], [w, 0, w, h], [w, h, 0, h], [0, h, 0, 0]]
    while len(rects) < n:
        order = sorted(range(len(rects)), key=lambda i: -(rects[i][2] - rects[i][0]) * (rects[i][3] - rects[i][1]))
        for i in order:
            x0, y0, x1, y1 = rects[i]
            vertical = (x1 - x0) >= (y1 - y0)  # a vertical wall splits the longer x side
            length = (x1 - x0) if vertical else (y1 - y0)
            if length < 2 * ROOM_MIN:
                continue
            lo, hi = max(ROOM_MIN / length, 0.35), min(1 - ROOM_MIN / length, 0.65)
            cut = round(((x0 if vertical else y0) + length * rng.uniform(lo, hi)) * 10) / 10
            if vertical:
                rects[i:i + 1] = [(x0, y0, cut, y1), (cut, y0, x1, y1)]
                walls.append([cut, y0, cut, y1])
            else:
                rects[i:i + 1] = [(x0, y0, x1, cut), (x0, cut, x1, y1)]
                walls.append([x0, cut, x1, cut])
            break
        else:
            return None
    return rects, walls


def shared_wall(a: tuple, b: tuple) -> tuple[str, float, float, float] | None:
    """(axis, at, lo, hi) of the wall two rooms share, or None."""
    for axis, (a0, a1, b0, b1, a_lo, a_hi, b_lo, b_hi) in (
            ("x", (a[2], a[0], b[0], b[2], a[1], a[3], b[1], b[3])),
            ("y", (a[3], a[1], b[1], b[3], a[0], a[2], b[0], b[2]))):
        for at, other in ((a0, b0), (a1, b1)):
            if abs(at - other) < 1e-6:
                lo, hi = max(a_lo, b_lo), min(a_hi, b_hi)
                if hi - lo > 0:
                    return axis, at, lo, hi
    return None


def spanning_tree(rng: np.random.Generator, adjacent: dict[int, list[int]], n: int) -> list[tuple[int, int]]:
    """Random spanning tree (grown from a random room); [] when the rooms are not connected."""
    seen = {int(rng.integers(n))}
    edges = []
    while len(seen) < n:
        frontier = sorted((a, b) for a in seen for b in adjacent[a] if b not in seen)
        if not frontier:
            return []
        a, b = frontier[int(rng.integers(len(frontier)))]
        seen.add(b)
        edges.append((a, b))
    return edges


def degrees(edges: list[tuple[int, int]], n: int) -> list[int]:
    deg = [0] * n
    for a, b in edges:
        deg[a] += 1
        deg[b] += 1
    return deg


# ---------------------------------------------------------------- doors

def place_link(d: Draft, kind: str, a: int, b: int, wall: tuple, width: float) -> Link | None:
    axis, at, lo, hi = wall
    lo, hi = lo + JUNCTION_CLEAR, hi - JUNCTION_CLEAR - width
    if hi < lo:
        return None
    link = Link(kind, a, b, axis, at, round(d.rng.uniform(lo, hi), 2), width)
    if kind != "opening":
        into = b if kind == "hazard" else (a, b)[int(d.rng.integers(2))]  # the room the leaf swings into
        p0, p1 = (np.array(p) for p in link.gap())
        if d.rng.random() < 0.5:
            p0, p1 = p1, p0
        c = (p1 - p0) / width
        into_dir = _into(d.rooms[into].rect, link)
        sign = 1 if (-c[1] * into_dir[0] + c[0] * into_dir[1]) > 0 else -1
        link.door = {"id": "", "hinge": [_r(p0[0]), _r(p0[1])], "closed_yaw": _r(math.degrees(math.atan2(c[1], c[0]))),
                     "width": width, "opens": "left" if sign > 0 else "right",
                     "angle": list(PASSAGE_OPEN_DEG) if kind == "passage" else [0, 90]}
    return link


def _into(rect: tuple, link: Link) -> np.ndarray:
    """Unit vector from the link's wall into the room `rect`."""
    cx, cy = (rect[0] + rect[2]) / 2, (rect[1] + rect[3]) / 2
    if link.axis == "x":
        return np.array([math.copysign(1.0, cx - link.at), 0.0])
    return np.array([0.0, math.copysign(1.0, cy - link.at)])


def door_check_pose(door: Door, side: str) -> tuple[np.ndarray, np.ndarray]:
    """(where to stand, the floor point to look at), both x, y, for checking a door: in front of the wall on the side the
    leaf does not swing to ("front"), or diagonally on its swing side ("swing"); every leaf position is
    then seen obliquely. The look-at point is near the hinge."""
    h = np.asarray(door.hinge, float)
    c = np.array([math.cos(door.closed_yaw), math.sin(door.closed_yaw)])
    n = np.array([-c[1], c[0]]) * door.sign  # the side the leaf swings to
    if side == "front":
        return h + 0.2 * c - 1.0 * n, h + 0.35 * c
    # swing side: beside the open leaf's line, looking at the hinge: the floor lines of the leaf
    # then stay within the image method's 30 deg of horizontal (from a diagonal stand they did not)
    return h - 0.3 * c + 1.3 * n, h


def lamp_check_pose(lamp: Lamp, into_room, distance: float = LAMP_STAND_M) -> np.ndarray:
    """Where to stand to check a lamp: `distance` from it into the room."""
    return np.array([lamp.x, lamp.y]) + distance * _unit(into_room)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def add_links(d: Draft) -> None:
    """Tree edges become doorways, passage doors or (into dead-end rooms) hazard doors; some extra
    doorways between walk-through rooms make loops."""
    n = len(d.rooms)
    rects = [r.rect for r in d.rooms]
    walls = {(a, b): w for a in range(n) for b in range(a + 1, n) if (w := shared_wall(rects[a], rects[b]))}
    adjacent = {i: [] for i in range(n)}
    for a, b in walls:
        if walls[a, b][3] - walls[a, b][2] >= 2 * JUNCTION_CLEAR + max(OPENING_W):
            adjacent[a].append(b)
            adjacent[b].append(a)
    tree = spanning_tree(d.rng, adjacent, n)
    if not tree:
        raise _Retry("rooms not connected")
    deg = degrees(tree, n)
    leaves = [i for i in range(n) if deg[i] == 1]
    dead = list(d.rng.permutation(leaves)[:int(d.rng.integers(1, min(len(leaves), n - 2, 3) + 1))])
    for i in dead:
        d.rooms[i].walk = False
    kinds = []
    for a, b in tree:
        if not d.rooms[a].walk or not d.rooms[b].walk:
            a, b = (a, b) if d.rooms[a].walk else (b, a)  # b: the dead-end room
            kinds.append(("hazard", a, b))
        else:
            kinds.append(("passage" if d.rng.random() < 0.5 else "opening", a, b))
    walk_links = [k for k in kinds if k[0] != "hazard"]
    if walk_links and not any(k[0] == "passage" for k in walk_links):  # some doors on the robot's route
        i = kinds.index(walk_links[int(d.rng.integers(len(walk_links)))])
        kinds[i] = ("passage",) + kinds[i][1:]
    in_tree = {tuple(sorted(e)) for e in tree}
    for a, b in sorted(walls):
        if (a, b) not in in_tree and b in adjacent[a] and d.rooms[a].walk and d.rooms[b].walk and d.rng.random() < 0.3:
            kinds.append(("opening", a, b))
    for kind, a, b in kinds:
        width = {"passage": PASSAGE_W, "opening": round(d.rng.uniform(*OPENING_W), 1),
                 "hazard": round(d.rng.uniform(*HAZARD_W), 1)}[kind]
        link = place_link(d, kind, a, b, walls[tuple(sorted((a, b)))], width)
        if link is None:
            raise _Retry("no room for a door")
        d.links.append(link)
    for k, link in enumerate(ln for ln in d.links if ln.door):
        link.door["id"] = f"d_{d.rooms[link.b if link.kind == 'hazard' else link.a].name}_{k}"
    for link in d.links:  # nothing stands in a doorway, before it or in a leaf's sweep
        centre = link.centre()
        for room in (link.a, link.b):
            into = _into(d.rooms[room].rect, link)
            for depth in (0.3, 0.9, 1.4):
                d.keep_out.append((centre + depth * into, link.width / 2 + 0.45))


class _Retry(Exception):
    """This draw does not make a house: the generator draws again."""


# ---------------------------------------------------------------- lamps

def add_lamps(d: Draft) -> None:
    walk = [i for i, r in enumerate(d.rooms) if r.walk]
    count = min(len(walk), int(d.rng.integers(1, 4)))
    for i in sorted(d.rng.permutation(walk)[:count]):
        x0, y0, x1, y1 = d.rooms[i].rect
        corners = [((x0, y0), (1, 1)), ((x1, y0), (-1, 1)), ((x1, y1), (-1, -1)), ((x0, y1), (1, -1))]
        for k in d.rng.permutation(4):
            (cx, cy), (sx, sy) = corners[k]
            pos = np.array([cx + sx * LAMP_INSET, cy + sy * LAMP_INSET])
            if all(_gap_distance(link, pos) >= 1.2 for link in d.links):
                lamp_id = f"l_{d.rooms[i].name}"
                d.lamps.append({"id": lamp_id, "x": _r(pos[0]), "y": _r(pos[1]), "z": LAMP_Z, "on": "random"})
                d.lamp_dirs[lamp_id] = [sx, sy]
                stand = pos + LAMP_STAND_M * _unit((sx, sy))
                d.keep_out += [(pos, 0.45), ((pos + stand) / 2, 0.5), (stand, 0.6)]
                break


def _gap_distance(link: Link, p: np.ndarray) -> float:
    a, b = (np.array(q) for q in link.gap())
    t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t * (b - a))))


# ---------------------------------------------------------------- furniture

def add_furniture(d: Draft) -> None:
    for i, room in enumerate(d.rooms):
        x0, y0, x1, y1 = room.rect
        kinds = ROOM_FURNITURE[room.name]
        for name in d.rng.permutation(kinds)[:int(d.rng.integers(1, min(3, len(kinds)) + 1))]:
            for _ in range(12):
                item = _wall_item(d, room.rect, str(name))
                if item and _fits(d, room.rect, item) and _still_navigable(d, item):
                    d.furniture.append(item)
                    break
        if room.walk and min(x1 - x0, y1 - y0) >= 4.0 and d.rng.random() < 0.6:
            name = str(d.rng.choice(sorted(CENTRE_ITEMS)))
            sx, sy, sz, color = CENTRE_ITEMS[name]
            cx = (x0 + x1) / 2 + d.rng.uniform(-0.5, 0.5)
            cy = (y0 + y1) / 2 + d.rng.uniform(-0.5, 0.5)
            item = _box(f"{name}_{room.name}", cx, cy, sx, sy, sz, color)
            if _fits(d, room.rect, item, gap=1.0) and _still_navigable(d, item):
                d.furniture.append(item)


def _box(name: str, x: float, y: float, sx: float, sy: float, sz: float, color) -> dict:
    return {"name": name, "x": _r(x), "y": _r(y), "size": [_r(sx), _r(sy), _r(sz)], "color": list(color)}


def _wall_item(d: Draft, rect: tuple, name: str) -> dict | None:
    length, depth, height, color = WALL_ITEMS[name]
    x0, y0, x1, y1 = rect
    side = int(d.rng.integers(4))
    off = WALL_T / 2 + 0.02 + depth / 2
    if side in (0, 2):  # south / north wall: along x
        if x1 - x0 < length + 0.4:
            return None
        x = d.rng.uniform(x0 + 0.2 + length / 2, x1 - 0.2 - length / 2)
        y = y0 + off if side == 0 else y1 - off
        return _box(f"{name}_{len(d.furniture)}", x, y, length, depth, height, color)
    if y1 - y0 < length + 0.4:
        return None
    y = d.rng.uniform(y0 + 0.2 + length / 2, y1 - 0.2 - length / 2)
    x = x0 + off if side == 3 else x1 - off
    return _box(f"{name}_{len(d.furniture)}", x, y, depth, length, height, color)


def _rect_of(item: dict) -> tuple[float, float, float, float]:
    sx, sy = item["size"][0] / 2, item["size"][1] / 2
    return item["x"] - sx, item["y"] - sy, item["x"] + sx, item["y"] + sy


def _rect_distance(r: tuple, p: np.ndarray) -> float:
    dx = max(r[0] - p[0], 0.0, p[0] - r[2])
    dy = max(r[1] - p[1], 0.0, p[1] - r[3])
    return math.hypot(dx, dy)


def _fits(d: Draft, room: tuple, item: dict, gap: float = 0.1) -> bool:
    r = _rect_of(item)
    if r[0] < room[0] or r[1] < room[1] or r[2] > room[2] or r[3] > room[3]:
        return False
    if any(_rect_distance(r, c) < rad for c, rad in d.keep_out):
        return False
    for other in d.furniture:
        o = _rect_of(other)
        if r[0] < o[2] + gap and o[0] < r[2] + gap and r[1] < o[3] + gap and o[1] < r[3] + gap:
            return False
    return True


def _still_navigable(d: Draft, item: dict) -> bool:
    d.furniture.append(item)
    try:
        return navigable(d)
    finally:
        d.furniture.pop()


# ---------------------------------------------------------------- checks on the grid

def describe(d: Draft, name: str, landmarks: list[dict] | None = None, robots: dict | None = None) -> dict:
    return {
        "name": name, "wall": {"height": WALL_H, "thickness": WALL_T},
        "walls": [[_r(v) for v in w] for w in d.walls],
        "openings": [{"from": [_r(v) for v in ln.gap()[0]], "to": [_r(v) for v in ln.gap()[1]]}
                     for ln in d.links if ln.kind == "opening"],
        "rooms": [{"name": r.name, "rect": [_r(r.rect[0] + WALL_T / 2), _r(r.rect[1] + WALL_T / 2),
                                            _r(r.rect[2] - WALL_T / 2), _r(r.rect[3] - WALL_T / 2)]} for r in d.rooms],
        "doors": [dict(ln.door) for ln in d.links if ln.door],
        "lamps": [dict(lp) for lp in d.lamps], "furniture": [dict(f) for f in d.furniture],
        "landmarks": landmarks or [], "robots": robots or {},
        "hazards": {"doors": {ln.door["id"]: "front" for ln in d.links if ln.kind == "hazard"},
                    "lamps": {k: list(v) for k, v in d.lamp_dirs.items()},
                    "passages": [ln.door["id"] for ln in d.links if ln.kind == "passage"]},
    }


def blocked_grid(desc: dict) -> tuple[np.ndarray, tuple[float, float]]:
    """Occupied-or-unknown cells (iy growing with y) of the house as the robot meets it: walls,
    furniture, lamps, passage doors anywhere in their open range, hazard doors closed."""
    hz = desc["hazards"]
    out = None
    for passage_deg in PASSAGE_OPEN_DEG:
        doors = {i: 0.0 for i in hz["doors"]} | {i: passage_deg for i in hz["passages"]}
        grid = build_grid_map(load_plan(desc, 0, {"doors": doors}), GRID_RES, include_doors=True)
        blocked = np.flipud(grid.image != FREE)
        out = blocked if out is None else out | blocked
    return out, (grid.origin[0], grid.origin[1])


def key_points(desc: dict) -> dict[str, np.ndarray]:
    """Every pose the robot must reach: each hazard's check pose and both sides of each walk-through
    connection."""
    plan = load_plan(desc, 0)
    hz = desc["hazards"]
    pts = {}
    for door in plan.doors:
        if door.id in hz["doors"]:
            pts[f"check:{door.id}"] = door_check_pose(door, hz["doors"][door.id])[0]
    for lamp in plan.lamps:
        if lamp.id in hz["lamps"]:
            pts[f"check:{lamp.id}"] = lamp_check_pose(lamp, hz["lamps"][lamp.id])
    return pts


def navigable(d: Draft) -> bool:
    desc = describe(d, "draft")
    blocked, origin = blocked_grid(desc)
    free = ndimage.distance_transform_edt(~blocked) * GRID_RES > NAV_RADIUS
    labels, _ = ndimage.label(free)
    pts = list(key_points(desc).values())
    for link in d.links:
        if link.kind != "hazard":
            pts += [link.centre() + 1.3 * _into(d.rooms[r].rect, link) for r in (link.a, link.b)]  # past a leaf
    seen = {int(labels[_cell(p, origin)]) for p in pts}
    return len(seen) == 1 and 0 not in seen


def _cell(p, origin) -> tuple[int, int]:
    return int((p[1] - origin[1]) / GRID_RES), int((p[0] - origin[0]) / GRID_RES)


# ---------------------------------------------------------------- landmarks and start poses

def add_landmarks(d: Draft) -> list[dict]:
    """The installer's rule (module docstring) on every wall face of every room."""
    out = []
    obstacles = [_rect_of(f) for f in d.furniture]
    lamps = [np.array([lp["x"], lp["y"]]) for lp in d.lamps]
    hinges = [np.array(ln.door["hinge"]) for ln in d.links if ln.door]
    for room in d.rooms:
        x0, y0, x1, y1 = room.rect
        faces = {  # side: (start point, direction along the wall, normal into the room, length)
            "S": ((x0, y0 + WALL_T / 2), (1, 0), (0, 1), x1 - x0), "E": ((x1 - WALL_T / 2, y0), (0, 1), (-1, 0), y1 - y0),
            "N": ((x1, y1 - WALL_T / 2), (-1, 0), (0, -1), x1 - x0), "W": ((x0 + WALL_T / 2, y1), (0, -1), (1, 0), y1 - y0)}
        for side, (start, along, normal, length) in faces.items():
            start, along, normal = np.array(start), np.array(along, float), np.array(normal, float)
            n = int(math.ceil((length - 2 * QR_END) / QR_SPACING)) + 1
            k = 0
            for t in np.linspace(QR_END, length - QR_END, n):
                spot = next((start + (t + s) * along for s in QR_SHIFTS
                             if QR_CORNER <= t + s <= length - QR_CORNER
                             and _spot_free(start + (t + s) * along, normal, d, obstacles, lamps, hinges)), None)
                if spot is None:
                    continue
                k += 1
                yaw = round(math.degrees(math.atan2(normal[1], normal[0])))
                out.append({"id": f"qr_{room.name}_{side.lower()}{k}", "text": f"QR-{room.name.upper()}-{side}{k}",
                            "x": _r(spot[0]), "y": _r(spot[1]), "z": QR_Z, "yaw": yaw, "size": QR_SIZE})
    return out


def _spot_free(p: np.ndarray, normal: np.ndarray, d: Draft, obstacles, lamps, hinges) -> bool:
    front = p + 0.4 * normal
    if any(_rect_distance(r, front) < 0.45 for r in obstacles):
        return False
    if any(_gap_distance(link, p) < 0.45 for link in d.links):
        return False
    if any(np.linalg.norm(p - h) < 0.6 for h in hinges):
        return False
    return all(np.linalg.norm(p - q) >= 0.75 for q in lamps)


def visible_landmarks(blocked: np.ndarray, origin, landmarks: list[dict], p, max_m: float = 4.0,
                      max_angle_deg: float = 60.0) -> list[str]:
    """Ids of the codes seen from p: within max_m, at most max_angle_deg off the code's normal, and no
    occupied cell on the straight line between."""
    out = []
    p = np.asarray(p, float)
    for m in landmarks:
        c = np.array([m["x"], m["y"]])
        v = p - c
        dist = float(np.linalg.norm(v))
        yaw = math.radians(m["yaw"])
        if dist > max_m or np.dot(v, (math.cos(yaw), math.sin(yaw))) < dist * math.cos(math.radians(max_angle_deg)):
            continue
        ts = np.linspace(0.12 / dist, 1.0, max(2, int(dist / (GRID_RES / 2))))
        pts = c + ts[:, None] * v
        rows = ((pts[:, 1] - origin[1]) / GRID_RES).astype(int)
        cols = ((pts[:, 0] - origin[0]) / GRID_RES).astype(int)
        if not blocked[rows, cols].any():
            out.append(m["id"])
    return out


def well_marked(desc: dict, min_spread: float = 0.5) -> bool:
    """Two codes at least min_spread apart in view from every check pose and start pose (the rule's
    density makes this so in nearly every house; a house where furniture hides too many is drawn
    again)."""
    blocked, origin = blocked_grid(desc)
    poses = list(key_points(desc).values()) + [r["pose"][:2] for r in desc["robots"].values()]
    where = {m["id"]: np.array([m["x"], m["y"]]) for m in desc["landmarks"]}
    for p in poses:
        seen = [where[i] for i in visible_landmarks(blocked, origin, desc["landmarks"], p)]
        if max((float(np.linalg.norm(a - b)) for a in seen for b in seen), default=0.0) <= min_spread:
            return False
    return True


def start_poses(d: Draft, desc: dict) -> dict:
    """A start pose per robot model, in a walk-through room, far from obstacles, connected to every
    key point."""
    blocked, origin = blocked_grid(desc)
    dist = ndimage.distance_transform_edt(~blocked) * GRID_RES
    labels, _ = ndimage.label(dist > NAV_RADIUS)
    main = int(labels[_cell(next(iter(key_points(desc).values())), origin)])
    robots = {}
    walk = [r for r in d.rooms if r.walk]
    # a type added to the table is drawn after the others: their poses stay (unless the new one sees
    # too few codes and the whole house is drawn again: well_marked)
    for kind in ROBOT_TYPES:
        room = walk[int(d.rng.integers(len(walk)))]
        x0, y0, x1, y1 = room.rect
        r0, c0 = _cell((x0, y0), origin)
        r1, c1 = _cell((x1, y1), origin)
        ok = (dist[r0:r1, c0:c1] >= START_CLEARANCE) & (labels[r0:r1, c0:c1] == main)
        cells = np.argwhere(ok)
        if not len(cells):
            raise _Retry(f"no start pose in {room.name}")
        r, c = cells[int(d.rng.integers(len(cells)))]
        x, y = origin[0] + (c0 + c + 0.5) * GRID_RES, origin[1] + (r0 + r + 0.5) * GRID_RES
        robots[kind] = {"pose": [_r(x), _r(y), int(d.rng.integers(-180, 180))]}
    return robots


# ---------------------------------------------------------------- the generator

def generate(seed: int) -> dict:
    """The house description of `seed` (a fresh dict each call; same seed, same house)."""
    return copy.deepcopy(_generate(int(seed)))


@functools.lru_cache(maxsize=16)
def _generate(seed: int) -> dict:
    for attempt in range(50):
        rng = np.random.default_rng([int(seed), zlib.crc32(b"house"), attempt])
        n = int(rng.integers(3, 9))
        split = split_rooms(rng, n)
        if split is None:
            continue
        rects, walls = split
        names = list(rng.permutation(ROOM_NAMES)[:n])
        d = Draft(rng, [Room(str(name), rect) for name, rect in zip(names, rects)], walls)
        try:
            add_links(d)
            add_lamps(d)
            if not navigable(d):
                continue
            if not d.lamps:
                continue
            add_furniture(d)
            desc = describe(d, f"generated-{seed}", add_landmarks(d))
            desc["robots"] = start_poses(d, desc)
        except _Retry:
            continue
        if well_marked(desc):
            return desc
    raise RuntimeError(f"no house could be generated from seed {seed}")


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    print(yaml.safe_dump(generate(int(args[0]) if args else 0), sort_keys=False, default_flow_style=None))
    return 0


if __name__ == "__main__":
    sys.exit(main())
