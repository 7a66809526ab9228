"""Path planners on inflated occupancy grids: grid Dijkstra / A* (scipy csgraph), OMPL planners,
line-of-sight shortcutting and corner tightening (any-angle smoothing), waypoint resampling.

All coordinates here are continuous cell coordinates (cell centres at integers, (x=ix, y=iy)).
Edge weights are in cells (1 or sqrt 2).
"""
from __future__ import annotations

import math
import time

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

SQRT2 = math.sqrt(2.0)
ALT_ROUNDING = 1e-2  # cells: float32 landmark distances (< 2000 cells) are exact to ~1e-4
OFFSETS8 = [(0, 1, 1.0), (1, 0, 1.0), (0, -1, 1.0), (-1, 0, 1.0),
            (1, 1, SQRT2), (1, -1, SQRT2), (-1, 1, SQRT2), (-1, -1, SQRT2)]  # (dy, dx, cost)


def inflate(blocked: np.ndarray, radius_cells: float) -> np.ndarray:
    """Cells whose centre is within radius_cells of an occupied cell centre (or off-map) are blocked."""
    padded = np.pad(~blocked, 1, constant_values=False)  # the map border counts as a wall
    dist = ndimage.distance_transform_edt(padded)[1:-1, 1:-1]
    return dist <= radius_cells


def _src(d: int, n: int) -> slice:
    return slice(max(0, -d), n - max(0, d))


def _dst(d: int, n: int) -> slice:
    return slice(max(0, -d) + d, n - max(0, d) + d)


class GridGraph:
    """8-connected graph of free cells (no corner cutting) as a CSR matrix, built once per cost map."""

    def __init__(self, free: np.ndarray) -> None:
        self.free = free
        h, w = free.shape
        self.shape = (h, w)
        idx = np.arange(h * w, dtype=np.int32).reshape(h, w)
        rows, cols, wts = [], [], []
        for dy, dx, c in OFFSETS8:
            ys, xs, yd, xd = _src(dy, h), _src(dx, w), _dst(dy, h), _dst(dx, w)
            ok = free[ys, xs] & free[yd, xd]
            if dy and dx:  # both orthogonal neighbours must be free
                ok &= free[yd, xs] & free[ys, xd]
            rows.append(idx[ys, xs][ok])
            cols.append(idx[yd, xd][ok])
            wts.append(np.full(int(ok.sum()), c))
        r, cc, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(wts)
        self.csr = sparse.csr_matrix((ww, (r, cc)), shape=(h * w, h * w))
        self.csr.sort_indices()
        self.row_of_edge = np.repeat(np.arange(h * w, dtype=np.int32), np.diff(self.csr.indptr))
        _, self.component = csgraph.connected_components(self.csr, directed=False)
        ys_all, xs_all = np.divmod(np.arange(h * w), w)
        self.ys, self.xs = ys_all.astype(np.float64), xs_all.astype(np.float64)

    def node(self, ix: int, iy: int) -> int:
        return iy * self.shape[1] + ix

    def octile_to(self, goal: int) -> np.ndarray:
        gy, gx = divmod(goal, self.shape[1])
        dy, dx = np.abs(self.ys - gy), np.abs(self.xs - gx)
        return np.maximum(dx, dy) + (SQRT2 - 1.0) * np.minimum(dx, dy)


def _trace(pred: np.ndarray, s: int, g: int, width: int) -> np.ndarray:
    nodes = [g]
    while nodes[-1] != s:
        nodes.append(int(pred[nodes[-1]]))
    nodes.reverse()
    ys, xs = np.divmod(np.asarray(nodes), width)
    return np.stack([xs, ys], axis=1).astype(np.float64)


def dijkstra_path(graph: GridGraph, s: int, g: int) -> np.ndarray | None:
    """Plain single-source Dijkstra (csgraph); None when the goal is unreachable."""
    if graph.component[s] != graph.component[g]:
        return None
    dist, pred = csgraph.dijkstra(graph.csr, indices=s, return_predecessors=True)
    if not np.isfinite(dist[g]):
        return None
    return _trace(pred, s, g, graph.shape[1])


def landmark_distances(graph: GridGraph, count: int = 8) -> np.ndarray:
    """Graph distances from `count` landmarks picked by farthest-point selection (ALT heuristic
    tables), shape (count, N), float32 (half the memory traffic per query; A* allows for the rounding);
    inf where unreachable. Built once per cost map."""
    free_nodes = np.flatnonzero(np.diff(graph.csr.indptr) > 0)
    if len(free_nodes) == 0:
        return np.zeros((0, graph.csr.shape[0]), np.float32)
    comp = graph.component[free_nodes]
    biggest = np.bincount(comp).argmax()
    nodes = free_nodes[comp == biggest]
    first = nodes[np.argmax(graph.xs[nodes] + graph.ys[nodes])]
    rows = [csgraph.dijkstra(graph.csr, indices=int(first))]
    for _ in range(count - 1):
        nearest = np.min(np.vstack(rows), axis=0)
        nearest[~np.isfinite(nearest)] = -1.0
        rows.append(csgraph.dijkstra(graph.csr, indices=int(np.argmax(nearest))))
    return np.vstack(rows).astype(np.float32)


def astar_path(graph: GridGraph, s: int, g: int, landmarks: np.ndarray | None = None) -> np.ndarray | None:
    """A* with the octile heuristic (tightened by ALT landmark bounds when tables are given: still
    admissible and consistent). Run as Dijkstra on reduced costs w - h(u) + h(v) >= 0, which expands
    nodes in A*'s order, under a bound on f that triples until the goal is settled: only nodes with
    f <= bound are expanded."""
    if graph.component[s] != graph.component[g]:
        return None
    h = graph.octile_to(g)
    if landmarks is not None and len(landmarks):
        in_goal_component = np.isfinite(landmarks[:, g])
        tables = landmarks if in_goal_component.all() else landmarks[in_goal_component]
        # inf off that component (never reached from s); minus float32 rounding, to stay admissible
        alt = np.abs(tables[:, g:g + 1] - tables).max(axis=0, initial=0.0) - ALT_ROUNDING
        np.fmax(h, alt, out=h)
    csr = graph.csr
    with np.errstate(invalid="ignore"):
        reduced = csr.data - h[graph.row_of_edge]
        reduced += h[csr.indices]
    np.fmax(reduced, 1e-9, out=reduced)  # nan (inf - inf) only off the start's component
    gr = sparse.csr_matrix((reduced, csr.indices, csr.indptr), shape=csr.shape)
    bound = 4.0 + 0.05 * h[s]
    while True:
        dist, pred = csgraph.dijkstra(gr, indices=s, return_predecessors=True, limit=bound)
        if np.isfinite(dist[g]):
            return _trace(pred, s, g, graph.shape[1])
        bound *= 3.0  # same component: the goal is reachable, a larger bound will settle it


# ---------- smoothing ----------

def segment_free(free: np.ndarray, a, b, step: float = 0.5) -> bool:
    return bool(segments_free(free, np.asarray(a, float), np.asarray([b], float), step)[0])


def segments_free(free: np.ndarray, a: np.ndarray, bs: np.ndarray, step: float = 0.25) -> np.ndarray:
    """Line of sight from point a to each of bs (cell coordinates): every sample's cell is free.

    Samples every quarter cell: a segment may clip the corner of an occupied cell of the *inflated*
    map by at most ~0.1 cell, never the obstacle itself (inflation is at least the robot's radius)."""
    d = bs - a
    n = int(np.ceil(np.max(np.hypot(d[:, 0], d[:, 1]), initial=0.0) / step)) + 1
    t = np.linspace(0.0, 1.0, n + 1)
    px = np.rint(a[0] + np.outer(d[:, 0], t)).astype(np.int64)
    py = np.rint(a[1] + np.outer(d[:, 1], t)).astype(np.int64)
    h, w = free.shape
    inside = (px >= 0) & (px < w) & (py >= 0) & (py < h)
    ok = np.zeros_like(inside)
    ok[inside] = free[py[inside], px[inside]]
    return ok.all(axis=1)


def corners(pts: np.ndarray) -> np.ndarray:
    """The path's ends and the points where its direction changes: a grid path's straight runs of
    cells are hundreds of points that shortcutting would otherwise test one by one."""
    if len(pts) <= 2:
        return pts
    d = np.diff(pts, axis=0)
    keep = np.ones(len(pts), bool)
    keep[1:-1] = np.any(d[1:] != d[:-1], axis=1)
    return pts[keep]


def shortcut(free: np.ndarray, pts: np.ndarray, chunk: int = 48) -> np.ndarray:
    """Greedy line-of-sight shortcutting: from each kept point jump to the furthest point reachable
    before the first blocked view (checked in vectorized chunks)."""
    if len(pts) <= 2:
        return pts
    out = [pts[0]]
    i, n = 0, len(pts)
    while i < n - 1:
        last_ok = i + 1
        j = i + 1
        while j < n:
            cand = pts[j:j + chunk]
            vis = segments_free(free, pts[i], cand)
            if vis.all():
                last_ok = j + len(cand) - 1
                j += len(cand)
                continue
            first_bad = int(np.argmin(vis))
            if first_bad > 0:
                last_ok = j + first_bad - 1
            break
        out.append(pts[last_ok])
        i = last_ok
    return np.asarray(out)


def pairs_free(free: np.ndarray, a: np.ndarray, b: np.ndarray, step: float = 0.25) -> np.ndarray:
    """Line of sight for each pair of points a[k] -> b[k] (cell coordinates)."""
    d = b - a
    n = int(np.ceil(np.max(np.hypot(d[:, 0], d[:, 1]), initial=0.0) / step)) + 1
    t = np.linspace(0.0, 1.0, n + 1)
    px = np.rint(a[:, :1] + np.outer(d[:, 0], t)).astype(np.int64)
    py = np.rint(a[:, 1:] + np.outer(d[:, 1], t)).astype(np.int64)
    h, w = free.shape
    inside = (px >= 0) & (px < w) & (py >= 0) & (py < h)
    ok = np.zeros_like(inside)
    ok[inside] = free[py[inside], px[inside]]
    return ok.all(axis=1)


_DEPTHS = np.linspace(1.0, 0.0, 17)[:-1]  # corner cut depths tried, deepest first


def tighten(free: np.ndarray, pts: np.ndarray, rounds: int = 6) -> np.ndarray:
    """Cut each corner as deep as line of sight allows (16 depths tested at once), then re-shortcut;
    repeat until the length stops improving. Pulls vertices off cell centres towards the taut
    (any-angle) path."""
    length = path_length(pts)
    for _ in range(rounds):
        if len(pts) <= 2:
            return pts
        new = [pts[0]]
        for k in range(1, len(pts) - 1):
            a, v, b = new[-1], pts[k], pts[k + 1]
            p = v + _DEPTHS[:, None] * (a - v)
            q = v + _DEPTHS[:, None] * (b - v)
            ok = pairs_free(free, p, q)
            if ok[0]:
                continue  # a -> b is clear: drop v
            if ok.any():
                i = int(np.argmax(ok))
                new.extend([p[i], q[i]])
            else:
                new.append(v)
        new.append(pts[-1])
        pts = shortcut(free, np.asarray(new))
        new_length = path_length(pts)
        if new_length > length - 1e-3:
            break
        length = new_length
    return pts


def path_length(pts: np.ndarray) -> float:
    return float(np.hypot(*np.diff(pts, axis=0).T).sum()) if len(pts) > 1 else 0.0


def resample(pts: np.ndarray, spacing: float) -> np.ndarray:
    """Points along the polyline no further apart than spacing; keeps every corner."""
    out = [pts[0]]
    for a, b in zip(pts[:-1], pts[1:]):
        seg = float(np.hypot(*(b - a)))
        k = max(1, int(math.ceil(seg / spacing - 1e-9)))
        for t in np.arange(1, k + 1) / k:
            out.append(a + t * (b - a))
    return np.asarray(out)


# ---------- OMPL ----------

OMPL_PLANNERS = ("rrtconnect", "rrtstar", "bitstar", "prmstar")


def ompl_path(free: np.ndarray, start, goal, algorithm: str, time_limit: float) -> np.ndarray | None:
    """Plan in RealVector(2) over the grid with OMPL; validity = cell lookup in the free mask.
    Optimizing planners use the path length objective and spend the whole time limit."""
    from ompl import base as ob, geometric as og, util as ou

    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    h, w = free.shape
    space = ob.RealVectorStateSpace(2)
    bounds = ob.RealVectorBounds(2)
    bounds.setLow(0, -0.5)
    bounds.setHigh(0, w - 0.5)
    bounds.setLow(1, -0.5)
    bounds.setHigh(1, h - 0.5)
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)

    def valid(state) -> bool:
        ix, iy = int(state[0] + 0.5), int(state[1] + 0.5)
        return 0 <= ix < w and 0 <= iy < h and bool(free[iy, ix])

    si.setStateValidityChecker(valid)
    si.setStateValidityCheckingResolution(0.3 / max(h, w))
    si.setup()
    s, g = si.allocState(), si.allocState()
    s[0], s[1] = float(start[0]), float(start[1])
    g[0], g[1] = float(goal[0]), float(goal[1])
    ss = og.SimpleSetup(si)
    ss.setStartAndGoalStates(s, g)
    cls = {"rrtconnect": og.RRTConnect, "rrtstar": og.RRTstar, "bitstar": og.BITstar,
           "prmstar": og.PRMstar}[algorithm]
    if algorithm != "rrtconnect":
        ss.setOptimizationObjective(ob.PathLengthOptimizationObjective(si))
    ss.setPlanner(cls(si))
    t0 = time.perf_counter()
    ss.solve(time_limit)
    if not ss.haveExactSolutionPath():
        return None
    ss.simplifySolution(max(0.05, time_limit - (time.perf_counter() - t0)) if algorithm == "rrtconnect" else 0.1)
    p = ss.getSolutionPath()
    return np.array([[p.getState(i)[0], p.getState(i)[1]] for i in range(p.getStateCount())])
