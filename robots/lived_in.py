"""A house lived in after its map was made (issue 48.1: maps that lie).

The owner mapped the home once; since then chairs were pushed about, a basket and a bag were left on
the floor, a passage door the map shows wide open stands half closed, and a rug lies in the hall.
`live_in` draws those changes from a seed and returns the plan the WORLD is built from; the map
(scenarios/home_setup.py home_map) is still drawn from the plan as mapped, so the robot plans on the
old map and meets the rest with its sensors, the plan monitor, obstacle marks and re-planning.

Every change keeps the house usable, as people keep their own homes: a moved or added piece stays in
its room, off the walls, doors' swings, hazard stands and start poses (`keep_clear`), and every one
of those points stays reachable from the first at the robots' clearance; a change that would cut a
room off is not made. A rug changes no geometry: it multiplies the walking robot's foot slip while
the robot stands on it (robots/failure_modes.py NaoGait) and is drawn on the floor.

    plan, changes = live_in(mapped, LivedIn(seed=7), passages=["d_living"], keep_clear=[(1.0, 2.4)])
"""
from __future__ import annotations

import math
import zlib
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy import ndimage

from .floorplan import Box, Plan
from .gridmap import OCCUPIED, build_grid_map
from .qr import Wear

CLEAR_OF_POINTS_M = 0.6  # a moved piece stays this far from a stand or a start pose
GAP_M = 0.08  # and this far from walls and other furniture
RUG_COLOR = (0.55, 0.25, 0.2)


@dataclass(frozen=True)
class LivedIn:
    """How much changed since the map; every count is drawn where it fits, so fewer may happen."""
    seed: int = 0
    moved: int = 2  # furniture pieces pushed 0.2-0.6 m and turned
    added: int = 2  # boxes left on the floor, not on the map
    doors: int = 1  # passage doors at 45-70 degrees where the map shows them open
    rugs: int = 1
    rug_slip: float = 2.5  # foot slip on a rug, times the slip on the floor
    codes_worn: int = 6  # QR labels faded, blurred, glossy or partly covered (robots/qr.py Wear)
    codes_moved: int = 2  # labels re-stuck 0.1-0.3 m along their wall since they were measured
    codes_missing: int = 1  # labels gone

    def describe(self) -> dict:
        return asdict(self)


def live_in(mapped: Plan, knobs: LivedIn, *, passages: list[str], keep_clear: list[tuple[float, float]],
            clearance_m: float = 0.35) -> tuple[Plan, dict]:
    """The plan as lived in, and what changed (for the run's result)."""
    rng = np.random.default_rng([knobs.seed, zlib.crc32(b"lived-in"), zlib.crc32(mapped.name.encode())])
    plan = replace(mapped, furniture=list(mapped.furniture), doors=list(mapped.doors), rugs=list(mapped.rugs))
    changes: dict = {"moved": [], "added": [], "doors": [], "rugs": [], "knobs": knobs.describe()}
    check = _Reachability(keep_clear, clearance_m, mapped)

    for door_id in list(rng.permutation(passages))[:knobs.doors]:
        i = next(k for k, d in enumerate(plan.doors) if d.id == door_id)
        angle = float(rng.uniform(45.0, 70.0))
        trial = replace(plan, doors=[*plan.doors[:i], replace(plan.doors[i], angle=angle), *plan.doors[i + 1:]])
        if check(trial):
            plan = trial
            changes["doors"].append({"id": str(door_id), "map_deg": mapped.doors[i].angle, "now_deg": round(angle, 1)})

    for i in list(rng.permutation(len(plan.furniture))):
        if len(changes["moved"]) >= knobs.moved:
            break
        old = plan.furniture[i]
        for _ in range(12):
            step, heading = rng.uniform(0.2, 0.6), rng.uniform(-math.pi, math.pi)
            new = replace(old, x=old.x + step * math.cos(heading), y=old.y + step * math.sin(heading),
                          yaw=old.yaw + float(rng.uniform(-0.5, 0.5)))
            others = plan.furniture[:i] + plan.furniture[i + 1:]
            trial = replace(plan, furniture=[*plan.furniture[:i], new, *plan.furniture[i + 1:]])
            if _fits(new, plan, others, keep_clear) and check(trial):
                plan = trial
                changes["moved"].append({"name": old.name, "from": [round(old.x, 2), round(old.y, 2)],
                                         "to": [round(new.x, 2), round(new.y, 2)]})
                break

    for n in range(knobs.added):
        for _ in range(30):
            room = plan.rooms[int(rng.integers(len(plan.rooms)))]
            x0, y0, x1, y1 = room.rect
            sx, sy, sz = rng.uniform(0.25, 0.5), rng.uniform(0.25, 0.5), rng.uniform(0.3, 0.7)
            box = Box(f"left-{n + 1}", float(rng.uniform(x0 + sx, x1 - sx)), float(rng.uniform(y0 + sy, y1 - sy)),
                      float(sx), float(sy), float(sz), float(rng.uniform(-math.pi, math.pi)), 0.0,
                      tuple(float(c) for c in rng.uniform(0.2, 0.8, 3)))
            trial = replace(plan, furniture=[*plan.furniture, box])
            if _fits(box, plan, plan.furniture, keep_clear) and check(trial):
                plan = trial
                changes["added"].append({"name": box.name, "at": [round(box.x, 2), round(box.y, 2)],
                                         "size": [round(sx, 2), round(sy, 2), round(sz, 2)]})
                break

    for n in range(knobs.rugs):
        room = plan.rooms[int(rng.integers(len(plan.rooms)))]
        x0, y0, x1, y1 = room.rect
        sx, sy = min(2.0, (x1 - x0) * 0.6), min(1.4, (y1 - y0) * 0.6)
        rug = Box(f"rug-{n + 1}", (x0 + x1) / 2 + float(rng.uniform(-0.2, 0.2)) * (x1 - x0 - sx),
                  (y0 + y1) / 2 + float(rng.uniform(-0.2, 0.2)) * (y1 - y0 - sy), sx, sy, 0.006, 0.0, 0.0, RUG_COLOR)
        plan = replace(plan, rugs=[*plan.rugs, rug], rug_slip=knobs.rug_slip)
        changes["rugs"].append({"name": rug.name, "room": room.name, "at": [round(rug.x, 2), round(rug.y, 2)],
                                "size": [round(sx, 2), round(sy, 2)], "slip_x": knobs.rug_slip})
    plan, changes["codes"] = _wear_codes(plan, knobs, rng)
    return plan, changes


def _wear_codes(plan: Plan, knobs: LivedIn, rng: np.random.Generator) -> tuple[Plan, list[dict]]:
    """The QR labels as years left them; the landmark list (the map's) still has them as measured."""
    marks = list(plan.landmarks)
    order = [int(i) for i in rng.permutation(len(marks))]
    missing = set(order[:knobs.codes_missing])
    moved = order[knobs.codes_missing:knobs.codes_missing + knobs.codes_moved]
    worn = order[knobs.codes_missing + knobs.codes_moved:][:knobs.codes_worn]
    out: list[dict] = []
    for i in moved:
        m = marks[i]
        shift = float(rng.choice([-1, 1]) * rng.uniform(0.1, 0.3))  # along the wall: the panel's right
        marks[i] = replace(m, x=m.x - shift * math.sin(m.yaw), y=m.y + shift * math.cos(m.yaw))
        out.append({"code": m.text, "change": "moved", "by_m": round(abs(shift), 3)})
    for i in worn:
        wear = Wear(fade=float(rng.uniform(0.1, 0.45)), blur_modules=float(rng.uniform(0.05, 0.3)),
                    glare=float(rng.uniform(0.0, 0.6)), glare_at=(float(rng.uniform(0.2, 0.8)), float(rng.uniform(0.2, 0.8))),
                    cover=float(rng.choice([0.0, rng.uniform(0.05, 0.25)])),
                    cover_side=str(rng.choice(["left", "right", "top", "bottom"])))
        marks[i] = replace(marks[i], wear=wear)
        out.append({"code": marks[i].text, "change": "worn", **{k: (round(v, 3) if isinstance(v, float) else v)
                                                               for k, v in asdict(wear).items()}})
    out += [{"code": marks[i].text, "change": "missing"} for i in sorted(missing)]
    return replace(plan, landmarks=[m for i, m in enumerate(marks) if i not in missing]), out


def _points(box: Box, n: int = 5) -> np.ndarray:
    """Points over a box's footprint (its corners included)."""
    u = np.linspace(-0.5, 0.5, n)
    local = np.array([(a * box.sx, b * box.sy) for a in u for b in u])
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    return local @ np.array([[c, s], [-s, c]]) + [box.x, box.y]


def _fits(box: Box, plan: Plan, others: list[Box], keep_clear: list[tuple[float, float]]) -> bool:
    corners = box.corners()
    rooms = [r for r in plan.rooms if all(r.rect[0] + GAP_M <= x <= r.rect[2] - GAP_M
                                          and r.rect[1] + GAP_M <= y <= r.rect[3] - GAP_M for x, y in corners)]
    if not rooms:
        return False  # in one room, off its walls
    if any(box.distance(*p) < CLEAR_OF_POINTS_M for p in keep_clear):
        return False
    if any(box.distance(*d.hinge) < d.width + 0.15 for d in plan.doors):
        return False  # out of every door's swing
    if any(box.distance(lp.x, lp.y) < 0.4 for lp in plan.lamps) or any(box.distance(m.x, m.y) < 0.3 for m in plan.landmarks):
        return False
    solid = [*plan.walls, *others]
    return not any(min(o.distance(x, y) for x, y in _points(box)) < GAP_M or
                   min(box.distance(x, y) for x, y in _points(o)) < GAP_M for o in solid
                   if math.dist((o.x, o.y), (box.x, box.y)) < (o.sx + o.sy + box.sx + box.sy) / 2 + 0.3)


class _Reachability:
    """Every keep-clear point reachable from the first by a disc of the clearance radius, doors as they stand."""

    def __init__(self, points: list[tuple[float, float]], clearance_m: float, mapped: Plan):
        self.points, self.clearance = points, clearance_m
        self.before = self.reached(mapped)  # what the mapped house allows (a tight stand may already fail)

    def __call__(self, plan: Plan) -> bool:
        return all(now or not was for now, was in zip(self.reached(plan), self.before))

    def reached(self, plan: Plan) -> list[bool]:
        if len(self.points) < 2:
            return [True] * len(self.points)
        grid = build_grid_map(plan, include_doors=True)
        blocked = grid.image == OCCUPIED
        radius = max(1, int(round(self.clearance / grid.resolution)))  # as the planner keeps it
        yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
        free = ~ndimage.binary_dilation(blocked, structure=xx ** 2 + yy ** 2 <= radius ** 2)
        labels, _ = ndimage.label(free)
        h = grid.image.shape[0]

        def label_at(p) -> int:
            col = int((p[0] - grid.origin[0]) / grid.resolution)
            row = h - 1 - int((p[1] - grid.origin[1]) / grid.resolution)
            window = labels[max(0, row - 3):row + 4, max(0, col - 3):col + 4]  # a stand hugging furniture
            found = window[window > 0]
            return int(np.bincount(found).argmax()) if found.size else 0

        first = label_at(self.points[0])
        return [first > 0 and label_at(p) == first for p in self.points]
