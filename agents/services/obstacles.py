"""Temporary obstacle layer of the Platform's cost maps: marks a RApp enters when its plan failed
because something stands in the way (a box in a doorway, a closed door, a person standing still).

Marks are discs in the map frame, kept per (user, map id): one user's marks never change another
user's plans or the map itself. Each lives until its owner clears the place or its TTL runs out.
`overlay(user, map)` is the map the planner uses: the base map itself while there are no live marks,
otherwise a copy with the discs blocked, kept in a small LRU so repeated plans with an unchanged
layer reuse its cost maps and graphs (`GridMap.cached`).
"""
from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from ontology.errors import ErrorCode
from ontology.services.navigation import AddObstacle, ClearObstacles, ListObstacles, ObstacleLayer, TempObstacle

from .errors import ServiceError
from .maps import GridMap, MapStore

MAX_MARKS = 100  # per (user, map)
OVERLAYS_PER_LAYER = 3  # cost maps of recent layer states kept per (user, map)
OVERLAYS_TOTAL = 8  # over the whole store: each holds its own graphs (~14 MB a margin, 20 m x 20 m map)


@dataclass(frozen=True)
class Mark:
    id: str
    x: float  # m, map frame
    y: float
    radius_m: float
    expires_at: float  # store clock
    note: str = ""

    @property
    def shape(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.radius_m)


@dataclass(eq=False)
class OverlayMap(GridMap):
    """A base map with temporary obstacle discs blocked: `base` is the map as uploaded, `marks` the
    discs drawn in."""

    base: GridMap | None = None
    marks: tuple[Mark, ...] = ()


def disc_mask(m: GridMap, marks) -> np.ndarray:
    """Cells whose centre lies within a mark's radius (and the cell holding its centre)."""
    out = np.zeros_like(m.blocked)
    for k in marks:
        cx, cy = m.world_to_cell(k.x, k.y)
        r = k.radius_m / m.resolution
        x0, x1 = max(0, math.ceil(cx - r)), min(m.width - 1, math.floor(cx + r))
        y0, y1 = max(0, math.ceil(cy - r)), min(m.height - 1, math.floor(cy + r))
        if x0 <= x1 and y0 <= y1:
            xs, ys = np.arange(x0, x1 + 1), np.arange(y0, y1 + 1)[:, None]
            out[y0:y1 + 1, x0:x1 + 1] |= (xs - cx) ** 2 + (ys - cy) ** 2 <= r * r
        ix, iy = int(round(cx)), int(round(cy))
        if 0 <= ix < m.width and 0 <= iy < m.height:
            out[iy, ix] = True
    return out


def mapped_within(m: GridMap, x: float, y: float, dist_m: float) -> bool:
    """Whether an occupied (or unknown) cell of the map comes within dist_m of (x, y) (any part of
    the cell: a wall's face, not its cells' centres)."""
    cx, cy = m.world_to_cell(x, y)
    r = dist_m / m.resolution
    x0, x1 = max(0, math.ceil(cx - r - 0.5)), min(m.width - 1, math.floor(cx + r + 0.5))
    y0, y1 = max(0, math.ceil(cy - r - 0.5)), min(m.height - 1, math.floor(cy + r + 0.5))
    ys, xs = np.nonzero(m.blocked[y0:y1 + 1, x0:x1 + 1])
    dx = np.maximum(np.abs(xs + x0 - cx) - 0.5, 0.0)
    dy = np.maximum(np.abs(ys + y0 - cy) - 0.5, 0.0)
    return bool(np.any(dx * dx + dy * dy <= r * r))


@dataclass
class _Layer:
    marks: dict[str, Mark] = field(default_factory=dict)
    next_id: int = 1


class ObstacleLayers:
    """Thread-safe store of every user's marks per map. `clock` (seconds, monotonic) is injectable
    for tests."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._layers: dict[tuple[str, str], _Layer] = {}
        # (user, map id, mark shapes) -> (base map, overlay); LRU, most recent last
        self._overlays: OrderedDict[tuple, tuple[GridMap, OverlayMap]] = OrderedDict()
        # called (lock held) with (user, map id, live marks, next id) after an add or a clear that
        # dropped marks: the Platform keeps the layer (agents/services/saved.py keep_obstacles)
        self.on_change: Callable[[str, str, list[Mark], int], None] | None = None

    def restore(self, user: str, map_id: str, marks: list[tuple[str, float, float, float, float, str]],
                next_id: int) -> None:
        """Put back a kept layer: marks as (id, x, y, radius, seconds left, note)."""
        with self._lock:
            layer = self._layers.setdefault((user, map_id), _Layer())
            now = self._clock()
            for mid, x, y, r, left, note in marks:
                if left > 0:
                    layer.marks[mid] = Mark(mid, x, y, r, now + left, note)
            layer.next_id = max(layer.next_id, next_id)

    def _live(self, user: str, map_id: str, create: bool = False) -> _Layer:
        """The layer with expired marks dropped (call with the lock held); an empty one, not stored,
        for a user who never marked this map unless `create`."""
        key = (user, map_id)
        layer = self._layers.setdefault(key, _Layer()) if create else self._layers.get(key, _Layer())
        now = self._clock()
        for mid in [mid for mid, k in layer.marks.items() if k.expires_at <= now]:
            del layer.marks[mid]
        return layer

    def add(self, user: str, m: GridMap, x: float, y: float, radius_m: float, ttl_s: float,
            note: str = "", skip_within_m: float = 0.0) -> Mark | None:
        """The new mark, or None when the map's own obstacles lie within skip_within_m of (x, y)."""
        if not all(math.isfinite(v) for v in (x, y, radius_m, ttl_s)) or radius_m <= 0 or ttl_s <= 0:
            raise ServiceError("a mark needs a finite centre, a positive radius and a positive TTL",
                               ErrorCode.INVALID_ARGUMENT)
        if not m.contains(x, y):
            raise ServiceError(f"mark centre ({x:.2f}, {y:.2f}) is outside map {m.map_id!r}", ErrorCode.OUT_OF_RANGE)
        if skip_within_m > 0 and mapped_within(m, x, y, skip_within_m):
            return None
        with self._lock:
            layer = self._live(user, m.map_id, create=True)
            if len(layer.marks) >= MAX_MARKS:
                raise ServiceError(f"map {m.map_id!r} already holds {MAX_MARKS} temporary obstacle marks of "
                                   "this user, the most allowed: clear some first", ErrorCode.TOO_LARGE)
            mark = Mark(f"obs-{layer.next_id}", float(x), float(y), float(radius_m), self._clock() + ttl_s, note)
            layer.next_id += 1
            layer.marks[mark.id] = mark
            if self.on_change is not None:
                self.on_change(user, m.map_id, list(layer.marks.values()), layer.next_id)
            return mark

    def clear(self, user: str, map_id: str, x: float | None = None, y: float | None = None,
              radius_m: float = 0.0, everything: bool = False) -> int:
        """Drop the marks whose centre lies within radius_m of (x, y), or all; how many were dropped."""
        if not everything and (x is None or y is None or not math.isfinite(x) or not math.isfinite(y)
                               or not math.isfinite(radius_m) or radius_m < 0):
            raise ServiceError("clearing needs a finite place (x, y) and radius >= 0, or all",
                               ErrorCode.INVALID_ARGUMENT)
        with self._lock:
            layer = self._live(user, map_id)
            gone = [mid for mid, k in layer.marks.items()
                    if everything or math.hypot(k.x - x, k.y - y) <= radius_m + 1e-9]
            for mid in gone:
                del layer.marks[mid]
            if gone and self.on_change is not None:
                self.on_change(user, map_id, list(layer.marks.values()), layer.next_id)
            return len(gone)

    def marks(self, user: str, map_id: str) -> list[Mark]:
        """Live marks, oldest first."""
        with self._lock:
            return list(self._live(user, map_id).marks.values())

    def expires_in(self, mark: Mark) -> float:
        return max(0.0, mark.expires_at - self._clock())

    def overlay(self, user: str, m: GridMap) -> GridMap:
        """The map to plan on: m itself without live marks, else m with the discs blocked. Keyed by
        the live marks' shapes, which change on every add, clear and expiry (a layer version that
        also recurs when a mark is cleared and the same one entered again)."""
        marks = tuple(sorted(self.marks(user, m.map_id), key=lambda k: k.shape))
        if not marks:
            return m
        key = (user, m.map_id, tuple(k.shape for k in marks))
        with self._lock:
            hit = self._overlays.get(key)
            if hit is not None and hit[0] is m:  # not a map uploaded again under the same id
                self._overlays.move_to_end(key)
                return hit[1]
        over = OverlayMap(m.map_id, m.blocked | disc_mask(m, marks), m.resolution, m.origin, m.shared,
                          base=m, marks=marks)
        with self._lock:
            self._overlays[key] = (m, over)
            self._overlays.move_to_end(key)
            same = [k for k in self._overlays if k[:2] == key[:2]]
            for old in same[:max(0, len(same) - OVERLAYS_PER_LAYER)]:
                del self._overlays[old]
            while len(self._overlays) > OVERLAYS_TOTAL:
                self._overlays.popitem(last=False)
        return over


# ---------- the services ----------

class _State(Protocol):
    @property
    def maps(self) -> MapStore: ...

    @property
    def obstacles(self) -> ObstacleLayers: ...


class MarksContext(Protocol):
    """What these services read of their ServiceContext (agents/services/context.py, whose
    state holds the ObstacleLayers above: importing it here would make an import loop)."""

    @property
    def user(self) -> str: ...

    @property
    def state(self) -> _State: ...


def _map(req, ctx: MarksContext) -> GridMap:
    m = ctx.state.maps.get(ctx.user, req.map_id)
    if m is None:  # plan_path_2d answers PLAN_UNKNOWN_MAP; there is no ErrorCode of that name
        raise ServiceError(f"unknown map {req.map_id!r}", ErrorCode.NOT_FOUND)
    return m


def _layer(ctx: MarksContext, map_id: str, added: str = "") -> ObstacleLayer:
    store = ctx.state.obstacles
    return ObstacleLayer(map_id=map_id, added=added, obstacles=[
        TempObstacle(id=k.id, x=k.x, y=k.y, radius_m=k.radius_m, expires_in_s=store.expires_in(k), note=k.note)
        for k in store.marks(ctx.user, map_id)])


def add_obstacle(req: AddObstacle, ctx: MarksContext) -> ObstacleLayer:
    m = _map(req, ctx)
    mark = ctx.state.obstacles.add(ctx.user, m, req.x, req.y, req.radius_m, req.ttl_s, req.note, req.skip_within_m)
    return _layer(ctx, m.map_id, mark.id if mark else "")


def clear_obstacles(req: ClearObstacles, ctx: MarksContext) -> ObstacleLayer:
    m = _map(req, ctx)
    ctx.state.obstacles.clear(ctx.user, m.map_id, req.x, req.y, req.radius_m, everything=req.all)
    return _layer(ctx, m.map_id)


def list_obstacles(req: ListObstacles, ctx: MarksContext) -> ObstacleLayer:
    return _layer(ctx, _map(req, ctx).map_id)
