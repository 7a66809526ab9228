"""Navigation services: map upload / listing and 2-D path planning per robot type (paper 001).
Plans go round the caller's temporary obstacle marks (agents/services/obstacles.py) unless the
request says otherwise."""
from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np
from scipy import ndimage

from ontology.robot_types import ROBOT_TYPES
from ontology.services.common import Pose2D
from ontology.services.navigation import (
    PLAN_FOUND, PLAN_NOT_FOUND, PLAN_UNKNOWN_ALGORITHM, PLAN_UNKNOWN_MAP, PLAN_UNKNOWN_ROBOT,
    ListMaps, MapInfo, MapList, PlanPath2D, PlanPathReply, UploadMap,
)

from . import planning
from .context import ServiceContext
from .images import b64_bytes
from .maps import GridMap, parse_map
from .obstacles import OverlayMap

GRID_ALGORITHMS = ("astar", "dijkstra")
ALGORITHMS = GRID_ALGORITHMS + planning.OMPL_PLANNERS
ESCAPE_M = 0.25  # how far a start inside an obstacle's inflation may be from free space


def robot_radius(robot_type: str) -> float:
    """The footprint radius (m) the cost map keeps free round a robot type: its clearance radius
    (ontology/robot_types.py: what its collision protection needs, not its body)."""
    return ROBOT_TYPES[robot_type].clearance_radius_m


def map_info(m: GridMap) -> MapInfo:
    return MapInfo(map_id=m.map_id, width=m.width, height=m.height, resolution=m.resolution,
                   origin=list(m.origin), shared=m.shared)


def upload_map(req: UploadMap, ctx: ServiceContext) -> MapInfo:
    m = parse_map(req.map_id, b64_bytes(req.png_b64, "png_b64"), req.yaml_text)
    ctx.state.maps.add(ctx.user, m)
    return map_info(m)


def list_maps(req: ListMaps, ctx: ServiceContext) -> MapList:
    return MapList(maps=[map_info(m) for m in ctx.state.maps.visible(ctx.user)])


def free_cells(m: GridMap, robot_type: str, margin_m: float = 0.0) -> np.ndarray:
    """Free mask of the cost map: obstacles inflated by the robot's footprint radius plus margin_m
    (cached per margin). An overlay's is its base map's less the inflated marks, inflated only
    around them (inflating a union is the union of the inflations)."""
    margin_m = round(margin_m, 3)
    radius = (robot_radius(robot_type) + margin_m) / m.resolution
    if isinstance(m, OverlayMap) and m.base is not None:
        base = m.base
        return m.cached(("free", robot_type, margin_m),
                        lambda: _less_marks(free_cells(base, robot_type, margin_m), m.blocked & ~base.blocked, radius))
    return m.cached(("free", robot_type, margin_m), lambda: ~planning.inflate(m.blocked, radius))


def _less_marks(free: np.ndarray, marked: np.ndarray, radius: float) -> np.ndarray:
    """free without the cells within radius (cells) of a marked cell, computed on the marks' box."""
    ys, xs = np.nonzero(marked)
    if len(ys) == 0:
        return free
    pad = int(math.ceil(radius)) + 1
    y0, y1 = max(0, ys.min() - pad), min(free.shape[0], ys.max() + pad + 1)
    x0, x1 = max(0, xs.min() - pad), min(free.shape[1], xs.max() + pad + 1)
    out = free.copy()
    out[y0:y1, x0:x1] &= ndimage.distance_transform_edt(~marked[y0:y1, x0:x1]) > radius
    return out


def grid_graph(m: GridMap, robot_type: str, margin_m: float = 0.0) -> planning.GridGraph:
    margin_m = round(margin_m, 3)
    return m.cached(("graph", robot_type, margin_m), lambda: planning.GridGraph(free_cells(m, robot_type, margin_m)))


def landmarks(m: GridMap, robot_type: str, margin_m: float = 0.0):
    """ALT landmark tables (8 Dijkstra runs over the map, built once per cost map). An overlay
    builds none: its base map's tables are lower bounds of its distances too (marks only remove
    cells), so A* uses them when the base has them for this margin, else the octile distance alone."""
    margin_m = round(margin_m, 3)
    key = ("landmarks", robot_type, margin_m)
    if isinstance(m, OverlayMap) and m.base is not None:
        return m.base.peek(key)  # a peek: building them would cost more than the search saves
    return m.cached(key, lambda: planning.landmark_distances(grid_graph(m, robot_type, margin_m)))


def connected(m: GridMap, robot_type: str, margin_m: float, a, b) -> bool:
    """Whether cells a and b lie in one component of this margin's graph: its components are those
    of the free mask's 4-neighbourhood (a diagonal move needs both orthogonal cells free), so an
    overlay finds out without building the graph."""
    margin_m = round(margin_m, 3)
    free = free_cells(m, robot_type, margin_m)
    labels = m.cached(("labels", robot_type, margin_m), lambda: ndimage.label(free)[0])
    la, lb = (labels[int(round(c[1])), int(round(c[0]))] for c in (a, b))
    return bool(la) and la == lb


def nearest_free(m: GridMap, robot_type: str, margin_m: float, cell) -> tuple[tuple[float, float], float]:
    """The free cell (of this margin's mask) nearest to a continuous cell position, and its distance
    in metres (0 when the position's own cell is free)."""
    margin_m = round(margin_m, 3)
    free = free_cells(m, robot_type, margin_m)
    ix, iy = int(round(cell[0])), int(round(cell[1]))
    if free[iy, ix]:
        return (float(cell[0]), float(cell[1])), 0.0

    def build():
        _, idx = ndimage.distance_transform_edt(~free, return_indices=True)
        return idx

    idx = m.cached(("nearest", robot_type, margin_m), build)
    ny, nx = idx[0, iy, ix], idx[1, iy, ix]
    if not free[ny, nx]:  # no free cell at all
        return (float(cell[0]), float(cell[1])), math.inf
    return (float(nx), float(ny)), math.hypot(nx - cell[0], ny - cell[1]) * m.resolution


def _check_pose(m: GridMap, p: Pose2D, what: str) -> str:
    if not all(math.isfinite(v) for v in (p.x, p.y, p.theta)):
        return f"{what} pose is not finite"
    if not m.contains(p.x, p.y):
        return f"{what} pose ({p.x:.2f}, {p.y:.2f}) is outside the map"
    return ""


def plan_cells(m: GridMap, robot_type: str, algorithm: str, start_c, goal_c, time_limit: float,
               margin_m: float = 0.0):
    """Smoothed polyline in cell coordinates, or None. Grid planners snap ends to cell centres and
    put the exact start / goal back after the search."""
    free = free_cells(m, robot_type, margin_m)
    if algorithm in GRID_ALGORITHMS:
        if isinstance(m, OverlayMap) and not connected(m, robot_type, margin_m, start_c, goal_c):
            return None  # a margin the marks close: no graph built for it
        g = grid_graph(m, robot_type, margin_m)
        s_node = g.node(int(round(start_c[0])), int(round(start_c[1])))
        g_node = g.node(int(round(goal_c[0])), int(round(goal_c[1])))
        if algorithm == "astar":
            cells = planning.astar_path(g, s_node, g_node, landmarks(m, robot_type, margin_m))
        else:
            cells = planning.dijkstra_path(g, s_node, g_node)
        if cells is None:
            return None
        cells[0], cells[-1] = start_c, goal_c
        cells = planning.corners(cells)
    else:
        cells = planning.ompl_path(free, start_c, goal_c, algorithm, time_limit)
        if cells is None:
            return None
    return planning.tighten(free, planning.shortcut(free, cells), rounds=1)  # 1 round: <0.3% longer than 6, 4x faster


def margins(clearance_m: float) -> list[float]:
    """Margins tried, widest first: a route through a passage narrower than the robot plus its
    clearance keeps less of it (down to the bare footprint) rather than failing."""
    if clearance_m <= 0:
        return [0.0]
    return [clearance_m, clearance_m / 2, clearance_m / 4, 0.0]


def _base(m: GridMap) -> GridMap:
    return m.base if isinstance(m, OverlayMap) and m.base is not None else m


def _leave_marks(m: OverlayMap, rt: str, at) -> tuple[tuple[float, float] | None, str]:
    """A start whose footprint reaches into temporary obstacle marks (the robot stands next to what
    it marked) steps straight to the nearest cell free of them: at most as far as the footprint
    reaches in, along a segment clear of the map's own obstacles that never closes in on a mark's
    centre (it backs away from what it marked, never through it)."""
    out, dist = nearest_free(m, rt, 0.0, at)
    if dist == 0:
        return (float(at[0]), float(at[1])), ""
    p = np.asarray(m.cell_to_world(*at), float)
    q = np.asarray(m.cell_to_world(*out), float)
    reach = max(k.radius_m + robot_radius(rt) - math.hypot(*(p - (k.x, k.y))) for k in m.marks)
    if not math.isfinite(dist) or dist > reach + 2 * m.resolution:
        return None, "start pose is inside temporary obstacle marks, too deep to step out of them"
    if not planning.segment_free(free_cells(m.base, rt), at, out):
        return None, "start pose is inside temporary obstacle marks and cannot step out of them in a straight line"
    d = q - p
    for k in m.marks:  # those the step comes near must not be approached
        c = np.array([k.x, k.y])
        t = float(np.clip(np.dot(c - p, d) / max(float(np.dot(d, d)), 1e-12), 0.0, 1.0))
        closest = math.hypot(*(p + t * d - c))
        if closest < k.radius_m + robot_radius(rt) and closest < math.hypot(*(p - c)) - m.resolution:
            return None, "start pose is inside temporary obstacle marks; stepping out would cross one"
    return out, ""


def plan_with_clearance(m: GridMap, req: PlanPath2D, start_c, goal_c):
    """(cells, margin, reason): the path at the widest margin that connects start and goal.

    An end inside a margin (a goal near a wall) joins the path at the nearest cell that keeps it,
    by a straight segment clear of the bare footprint. A start inside the bare footprint's inflation
    (a robot that stopped against an obstacle) first steps straight to the nearest free cell, if that
    is within ESCAPE_M; then, on an overlay, out of the temporary marks (`_leave_marks`)."""
    rt = req.robot_type
    base = _base(m)
    hard = free_cells(m, rt)
    escape, dist = nearest_free(base, rt, 0.0, start_c)
    if base.blocked[int(round(start_c[1])), int(round(start_c[0]))]:
        return None, 0.0, "start pose is in an obstacle"
    if dist > ESCAPE_M:
        return None, 0.0, ("start pose is in an obstacle or too close to one for this robot "
                           f"(more than {ESCAPE_M:.2f} m from free space)")
    steps = [escape]
    if m is not base:
        out, reason = _leave_marks(m, rt, escape)
        if out is None:
            return None, 0.0, reason + " (clear them or plan with use_obstacles=False)"
        steps.append(out)
        escape = out
    if nearest_free(base, rt, 0.0, goal_c)[1] > 0:
        return None, 0.0, "goal pose is in an obstacle or too close to one for this robot"
    if m is not base and nearest_free(m, rt, 0.0, goal_c)[1] > 0:
        return None, 0.0, "goal pose is in a temporary obstacle mark or too close to one for this robot"
    reason = ""
    for margin in margins(req.clearance_m):
        ends = []
        for c in (escape, goal_c):
            entry, d = nearest_free(m, rt, margin, c)
            join_ok = d == 0 or (d <= margin + 2 * m.resolution and planning.segment_free(hard, c, entry))
            ends.append(entry if join_ok else None)
        if None in ends:
            reason = "an end of the path cannot join free space"
            continue
        cells = plan_cells(m, rt, req.algorithm, ends[0], ends[1], req.time_limit_s, margin)
        if cells is None:
            reason = "no collision-free path between start and goal for this robot"
            continue
        if margin > 0 and nearest_free(m, rt, margin, escape)[1] > 0:  # the start is inside the margin
            cells = _join(hard, np.asarray(escape, float), cells)
        pts = [np.asarray(start_c, float), *(np.asarray(p, float) for p in steps), *cells, np.asarray(goal_c, float)]
        keep = [pts[0]] + [q for prev, q in zip(pts, pts[1:]) if np.hypot(*(q - prev)) > 1e-9]
        return np.asarray(keep), margin, ""
    if m is not base:
        reason += _blame_marks(m, rt, escape, goal_c)
    return None, 0.0, reason


def _join(hard: np.ndarray, start: np.ndarray, cells: np.ndarray, look: int = 4) -> np.ndarray:
    """A start inside the margin joins the margin's path at the furthest of its first `look` vertices
    in straight sight for the bare footprint, not by a step to the nearest cell that keeps the margin:
    that step, sideways to where the path goes, made a leg start with a sharp turn, and a turn costs
    heading (an Elektron ran 17 cm off a 1.1 m leg after one)."""
    seen = [k for k in range(1, min(look, len(cells) - 1) + 1) if planning.segment_free(hard, start, cells[k])]
    return cells[max(seen):] if seen else cells


def _blame_marks(m: OverlayMap, rt: str, start_c, goal_c) -> str:
    """Whether the marks are what keeps start and goal apart: the map alone connects them for the
    bare footprint, the map with the marks does not."""
    n = len(m.marks)
    if connected(m.base, rt, 0.0, start_c, goal_c) and not connected(m, rt, 0.0, start_c, goal_c):
        return (f": the {n} temporary obstacle mark(s) on this map block every route (clear them with "
                "path_planning_clear_obstacles, or plan with use_obstacles=False)")
    return f" ({n} temporary obstacle mark(s) on this map)"


def plan_path_2d(req: PlanPath2D, ctx: ServiceContext) -> PlanPathReply:
    m = ctx.state.maps.get(ctx.user, req.map_id)
    return plan_on_map(req, m, lambda base: ctx.state.obstacles.overlay(ctx.user, base))


def plan_on_map(req: PlanPath2D, m: GridMap | None, overlay: Callable[[GridMap], GridMap]) -> PlanPathReply:
    """plan_path_2d on a map already looked up (None: unknown); `overlay(map)` is the map with the
    caller's temporary obstacle marks (used when the request asks for them). The service pool's
    workers call this with their cached copy of the map (agents/services/pool.py)."""
    t0 = time.perf_counter()
    if m is None:
        return PlanPathReply(plan_found=PLAN_UNKNOWN_MAP, reason=f"unknown map {req.map_id!r}")
    if req.robot_type not in ROBOT_TYPES:
        return PlanPathReply(plan_found=PLAN_UNKNOWN_ROBOT,
                             reason=f"unknown robot type {req.robot_type!r} (known: {', '.join(ROBOT_TYPES)})")
    if req.algorithm not in ALGORITHMS:
        return PlanPathReply(plan_found=PLAN_UNKNOWN_ALGORITHM,
                             reason=f"unknown algorithm {req.algorithm!r} (known: {', '.join(ALGORITHMS)})")
    for pose, what in ((req.start, "start"), (req.goal, "goal")):
        reason = _check_pose(m, pose, what)
        if reason:
            return PlanPathReply(plan_found=PLAN_NOT_FOUND, reason=reason)
    start_c, goal_c = m.world_to_cell(req.start.x, req.start.y), m.world_to_cell(req.goal.x, req.goal.y)
    if req.use_obstacles:
        m = overlay(m)
    used = len(m.marks) if isinstance(m, OverlayMap) else 0
    cells, margin, reason = plan_with_clearance(m, req, start_c, goal_c)
    elapsed = time.perf_counter() - t0
    if cells is None:
        return PlanPathReply(plan_found=PLAN_NOT_FOUND, planning_time_s=elapsed, reason=reason, obstacles_used=used)
    pts = planning.resample(cells, req.waypoint_spacing_m / m.resolution)
    xs, ys = m.cell_to_world(pts[:, 0], pts[:, 1])
    headings = np.arctan2(np.diff(ys), np.diff(xs))
    thetas = np.append(headings, req.goal.theta) if len(headings) else np.array([req.goal.theta])
    path = [Pose2D(x=float(x), y=float(y), theta=float(t)) for x, y, t in zip(xs, ys, thetas)]
    path[0] = Pose2D(x=req.start.x, y=req.start.y, theta=float(thetas[0]) if len(path) > 1 else req.start.theta)
    return PlanPathReply(plan_found=PLAN_FOUND, path=path, length_m=planning.path_length(cells) * m.resolution,
                         planning_time_s=elapsed, clearance_m=margin, obstacles_used=used)
