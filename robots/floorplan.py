"""Scenario (house) description: YAML -> plain geometry, with seeded random choices resolved.

YAML keys (metres, angles in degrees):
  name, wall: {height, thickness}
  walls:     [[x1, y1, x2, y2], ...]            segments; door gaps are cut out automatically
  rooms:     [{name, rect: [x0, y0, x1, y1]}]   named regions (start-pose sampling, labels)
  doors:     [{id, hinge: [x, y], closed_yaw, width, opens: left|right, angle: 30 | [lo, hi]}]
             angle 0 = closed (leaf in the wall line), 90 = open; a list is a seeded random range
  lamps:     [{id, x, y, z, on: true|false|random}]   z = shade centre height
  furniture: [{name, x, y, size: [sx, sy, sz], yaw, color: [r, g, b]}]   boxes standing on the floor
  landmarks: [{id, text, x, y, z, yaw, size}]   QR panels; yaw = panel normal (into the room),
             size = side of the QR symbol without quiet zone (default 0.25)
  robots:    {name: {pose: [x, y, theta]} | {room: name} | {region: [x0, y0, x1, y1]}}
  hazards:   {doors: {id: front|swing}, lamps: {id: [dx, dy]}, passages: [id]}   optional: what the owner's
             home description lists (doors checked and from which side, lamps and the direction into the
             room, doors left open for the robot); generated houses have it (robots/house_gen.py)
  acoustics: {rt60_s: 0.5}   optional: the rooms' reverberation time (robots/reverb.py); 0 or absent = none
Overrides (same keys): {"doors": {"d1": 45}, "lamps": {"l1": True}, "robots": {"nao": {"pose": [...]}},
                       "acoustics": {"rt60_s": 0.5}}
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .qr import Wear
from .reverb import checked_rt60

WALL_COLOR = (0.92, 0.90, 0.82)
FLOOR_COLOR = (0.36, 0.34, 0.33)
CEILING_COLOR = (0.80, 0.80, 0.80)
DOOR_COLOR = (0.58, 0.36, 0.17)
DOOR_THICKNESS = 0.04
DOOR_HEIGHT = 2.0


@dataclass
class Box:
    """Axis box rotated by yaw about z, standing on z0."""

    name: str
    x: float
    y: float
    sx: float
    sy: float
    sz: float
    yaw: float = 0.0  # radians
    z0: float = 0.0
    color: tuple[float, float, float] = WALL_COLOR

    def corners(self) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        hx, hy = self.sx / 2, self.sy / 2
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        return local @ np.array([[c, s], [-s, c]]) + [self.x, self.y]

    def distance(self, x: float, y: float) -> float:
        """2-D distance from a point to the box footprint (0 inside)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        dx, dy = x - self.x, y - self.y
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        ex = max(abs(lx) - self.sx / 2, 0.0)
        ey = max(abs(ly) - self.sy / 2, 0.0)
        return math.hypot(ex, ey)


@dataclass
class Door:
    id: str
    hinge: tuple[float, float]
    closed_yaw: float  # radians, direction hinge -> free end when closed
    width: float
    sign: int  # +1 opens counter-clockwise
    angle: float  # degrees, 0 closed

    def leaf_box(self, angle_deg: float | None = None) -> Box:
        a = self.angle if angle_deg is None else angle_deg
        yaw = self.closed_yaw + self.sign * math.radians(a)
        w = self.width - 0.02
        cx = self.hinge[0] + 0.01 * math.cos(yaw) + w / 2 * math.cos(yaw)
        cy = self.hinge[1] + 0.01 * math.sin(yaw) + w / 2 * math.sin(yaw)
        return Box(f"door:{self.id}", cx, cy, w, DOOR_THICKNESS, DOOR_HEIGHT, yaw, 0.0, DOOR_COLOR)


@dataclass
class Lamp:
    id: str
    x: float
    y: float
    z: float
    on: bool
    strength: float = 1.0  # light output, relative (robots/daylight.py draws several)


@dataclass
class Landmark:
    id: str
    text: str
    x: float
    y: float
    z: float
    yaw: float  # radians, panel normal
    size: float
    wear: Wear | None = None  # a worn print (robots/lived_in.py); None: as printed

    def corners(self) -> list[list[float]]:
        """Symbol corners in the world frame, as a viewer facing the panel sees them: TL, TR, BR, BL."""
        nx, ny = math.cos(self.yaw), math.sin(self.yaw)
        rx, ry = -ny, nx  # viewer's right when looking at the panel (against the normal)
        h = self.size / 2
        out = []
        for sr, su in ((-1, 1), (1, 1), (1, -1), (-1, -1)):
            out.append([self.x + sr * h * rx, self.y + sr * h * ry, self.z + su * h])
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, "text": self.text, "x": self.x, "y": self.y, "z": self.z,
                "yaw": self.yaw, "yaw_deg": math.degrees(self.yaw), "size": self.size,
                "corners": self.corners()}


@dataclass
class Room:
    name: str
    rect: tuple[float, float, float, float]


@dataclass
class Plan:
    name: str
    seed: int
    wall_height: float
    wall_thickness: float
    walls: list[Box]
    furniture: list[Box]
    doors: list[Door]
    lamps: list[Lamp]
    landmarks: list[Landmark]
    rooms: list[Room]
    robots: dict[str, dict[str, Any]] = field(default_factory=dict)
    hazards: dict[str, Any] = field(default_factory=dict)  # the description's `hazards` section
    rt60_s: float = 0.0  # the rooms' reverberation time: 0 = anechoic (robots/sound.py)
    rugs: list[Box] = field(default_factory=list)  # on the floor, no obstacle: feet slip more (robots/lived_in.py)
    rug_slip: float = 1.0  # foot slip on a rug, times the slip on the floor
    windows: list[Box] = field(default_factory=list)  # panes in the outside walls (robots/daylight.py)
    sky: float | None = None  # daylight through them, 0 night .. 1 clear noon; None: the studio light

    def slip_at(self, x: float, y: float) -> float:
        """How much more a walking robot's feet slip at (x, y) than on the bare floor."""
        return self.rug_slip if any(r.distance(x, y) == 0.0 for r in self.rugs) else 1.0

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        pts = np.vstack([b.corners() for b in self.walls])
        return float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max())

    def obstacles(self, include_doors: bool = True) -> list[Box]:
        out = list(self.walls) + list(self.furniture)
        out += [Box(f"lamp:{lp.id}", lp.x, lp.y, 0.4, 0.4, lp.z, 0.0, 0.0, (0.2, 0.2, 0.2)) for lp in self.lamps]
        if include_doors:
            out += [d.leaf_box() for d in self.doors]
        return out

    def room_at(self, x: float, y: float) -> str | None:
        """Name of the room whose rectangle holds (x, y), or None (walls, doorways, outside)."""
        return next((r.name for r in self.rooms if r.rect[0] <= x <= r.rect[2] and r.rect[1] <= y <= r.rect[3]), None)

    def room_volume(self, name: str) -> float:
        """m^3 of a room: its rectangle times the walls' height."""
        x0, y0, x1, y1 = next(r.rect for r in self.rooms if r.name == name)
        return (x1 - x0) * (y1 - y0) * self.wall_height

    def clearance(self, x: float, y: float) -> float:
        return min(b.distance(x, y) for b in self.obstacles())

    def rng(self, *key: str) -> np.random.Generator:
        return np.random.default_rng([self.seed, zlib.crc32("/".join(key).encode())])

    def start_pose(self, name: str, kind: str, radius: float) -> tuple[float, float, float]:
        spec = self.robots.get(name) or self.robots.get(kind) or {}
        if "pose" in spec:
            x, y, th = (list(spec["pose"]) + [0.0])[:3]
            return float(x), float(y), math.radians(float(th))
        if "room" in spec:
            region = next(r.rect for r in self.rooms if r.name == spec["room"])
        elif "region" in spec:
            region = tuple(spec["region"])
        elif self.rooms:
            region = self.rooms[0].rect
        else:
            region = self.bounds
        rng = self.rng("robot", name)
        x0, y0, x1, y1 = region
        for _ in range(2000):
            x, y = rng.uniform(x0 + radius, x1 - radius), rng.uniform(y0 + radius, y1 - radius)
            if self.clearance(x, y) > radius + 0.1:
                return float(x), float(y), float(rng.uniform(-math.pi, math.pi))
        raise ValueError(f"no free start pose for robot {name!r} in region {region}")


def _cut_walls(segments: list[list[float]], doors: list[Door], openings: list[dict], t: float,
               h: float) -> list[Box]:
    gaps = [(d.hinge, (d.hinge[0] + d.width * math.cos(d.closed_yaw), d.hinge[1] + d.width * math.sin(d.closed_yaw)))
            for d in doors]
    for o in openings:
        gaps.append((tuple(o["from"]), tuple(o["to"])))
    boxes = []
    for i, (x1, y1, x2, y2) in enumerate(segments):
        length = math.hypot(x2 - x1, y2 - y1)
        ux, uy = (x2 - x1) / length, (y2 - y1) / length
        keep = [(0.0, length)]
        for a, b in gaps:
            da = (a[0] - x1) * uy - (a[1] - y1) * ux
            db = (b[0] - x1) * uy - (b[1] - y1) * ux
            if abs(da) > t or abs(db) > t:
                continue
            ta = (a[0] - x1) * ux + (a[1] - y1) * uy
            tb = (b[0] - x1) * ux + (b[1] - y1) * uy
            lo, hi = min(ta, tb), max(ta, tb)
            nxt = []
            for s, e in keep:
                if hi <= s or lo >= e:
                    nxt.append((s, e))
                    continue
                if lo > s:
                    nxt.append((s, lo))
                if hi < e:
                    nxt.append((hi, e))
            keep = nxt
        for j, (s, e) in enumerate(keep):
            if e - s < 1e-3:
                continue
            # extend by half a thickness at both ends so corners close, except at gaps
            s_ext = s - t / 2 if s == 0.0 else s
            e_ext = e + t / 2 if e == length else e
            m = (s_ext + e_ext) / 2
            boxes.append(Box(f"wall{i}.{j}", x1 + ux * m, y1 + uy * m, e_ext - s_ext, t, h,
                             math.atan2(uy, ux), 0.0, WALL_COLOR))
    return boxes


def _merge(base: dict, overrides: dict | None) -> dict:
    return {**base, **(overrides or {})}


def load_plan(source: str | Path | dict, seed: int = 0, overrides: dict | None = None) -> Plan:
    """Parse a house description (path or dict) and resolve random choices with `seed`."""
    desc = source if isinstance(source, dict) else yaml.safe_load(Path(source).read_text())
    ov = overrides or {}
    wall = desc.get("wall", {})
    t, h = float(wall.get("thickness", 0.1)), float(wall.get("height", 2.4))
    plan = Plan(desc.get("name", "house"), seed, h, t, [], [], [], [], [], [],
                {k: _merge(v, ov.get("robots", {}).get(k)) for k, v in (desc.get("robots") or {}).items()})
    for k, v in ov.get("robots", {}).items():
        plan.robots.setdefault(k, v)
    for d in desc.get("doors", []):
        spec = ov.get("doors", {}).get(d["id"], d.get("angle", 0.0))
        if isinstance(spec, (list, tuple)):
            angle = float(plan.rng("door", d["id"]).uniform(spec[0], spec[1]))
        else:
            angle = float(spec)
        sign = -1 if str(d.get("opens", "left")) == "right" else 1
        plan.doors.append(Door(d["id"], tuple(map(float, d["hinge"])), math.radians(float(d.get("closed_yaw", 0))),
                               float(d.get("width", 0.9)), sign, angle))
    plan.walls = _cut_walls(desc.get("walls", []), plan.doors, desc.get("openings", []), t, h)
    for f in desc.get("furniture", []):
        sx, sy, sz = map(float, f["size"])
        plan.furniture.append(Box(f.get("name", "furniture"), float(f["x"]), float(f["y"]), sx, sy, sz,
                                  math.radians(float(f.get("yaw", 0))), 0.0,
                                  tuple(f.get("color", (0.45, 0.5, 0.6)))))
    for lamp in desc.get("lamps", []):
        # YAML 1.1 reads the key `on` as True: a file's `on: true` arrives under the key True
        spec = ov.get("lamps", {}).get(lamp["id"], lamp.get("on", lamp.get(True, "random")))
        on = bool(plan.rng("lamp", lamp["id"]).random() < 0.5) if spec == "random" else bool(spec)
        plan.lamps.append(Lamp(lamp["id"], float(lamp["x"]), float(lamp["y"]), float(lamp.get("z", 1.4)), on))
    for m in desc.get("landmarks", []):
        plan.landmarks.append(Landmark(str(m["id"]), str(m.get("text", m["id"])), float(m["x"]), float(m["y"]),
                                       float(m.get("z", 1.0)), math.radians(float(m.get("yaw", 0))),
                                       float(m.get("size", 0.25))))
    plan.rooms = [Room(r["name"], tuple(map(float, r["rect"]))) for r in desc.get("rooms", [])]
    plan.hazards = dict(desc.get("hazards") or {})
    plan.rt60_s = checked_rt60({**(desc.get("acoustics") or {}), **ov.get("acoustics", {})}.get("rt60_s", 0.0))
    return plan
