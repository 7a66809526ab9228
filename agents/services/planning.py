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


def source_cells(d: int, n: int) -> slice:
    """Along an axis of `n` cells, those whose neighbour at offset `d` is inside the grid."""
    return slice(max(0, -d), n - max(0, d))


def target_cells(d: int, n: int) -> slice:
    """Those neighbours: source_cells(d, n) moved by `d`."""
    return slice(max(0, -d) + d, n - max(0, d) + d)


class GridGraph:
    """8-connected graph of free cells (no corner cutting), built once per cost map: a CSR matrix
    (Dijkstra, components, landmark tables) and the same edges as a mask of allowed moves per cell
    (`moves[iy, ix, k]`: the move by OFFSETS8[k] is an edge), from which A* cuts the window it needs."""

    def __init__(self, free: np.ndarray) -> None:
        self.free = free
        h, w = free.shape
        self.shape = (h, w)
        idx = np.arange(h * w, dtype=np.int32).reshape(h, w)
        self.moves = np.zeros((h, w, 8), bool)
        rows, cols, wts = [], [], []
        for k, (dy, dx, c) in enumerate(OFFSETS8):
            ys, xs, yd, xd = source_cells(dy, h), source_cells(dx, w), target_cells(dy, h), target_cells(dx, w)
            ok = free[ys, xs] & free[yd, xd]
            if dy and dx:  # both orthogonal neighbours must be free
                ok &= free[yd, xs] & free[ys, xd]
            rows.append(idx[ys, xs][ok])
            cols.append(idx[yd, xd][ok])
            wts.append(np.full(int(ok.sum()), c))
            self.moves[ys, xs, k] = ok
        r, cc, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(wts)
        self.csr = sparse.csr_matrix((ww, (r, cc)), shape=(h * w, h * w))
        self.csr.sort_indices()
        _, self.component = csgraph.connected_components(self.csr, directed=False)

    def node(self, ix: int, iy: int) -> int:
        return iy * self.shape[1] + ix


def path_cells(pred: np.ndarray, s: int, g: int, width: int) -> np.ndarray:
    """Cells (x, y) from node s to node g along a predecessor array."""
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
    return path_cells(pred, s, g, graph.shape[1])


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
    ys, xs = np.divmod(nodes, graph.shape[1])
    first = nodes[np.argmax(xs + ys)]
    rows = [csgraph.dijkstra(graph.csr, indices=int(first))]
    for _ in range(count - 1):
        nearest = np.min(np.vstack(rows), axis=0)
        nearest[~np.isfinite(nearest)] = -1.0
        rows.append(csgraph.dijkstra(graph.csr, indices=int(np.argmax(nearest))))
    return np.vstack(rows).astype(np.float32)


def _octile(dx, dy):
    dx, dy = np.abs(dx), np.abs(dy)
    return np.maximum(dx, dy) + (SQRT2 - 1.0) * np.minimum(dx, dy)


def _extent(n: int, m: int, s: tuple[int, int], g: tuple[int, int], limit: float) -> tuple[int, int]:
    """Range [lo, hi) of the first coordinate (0..n-1; the second one in 0..m-1) holding every cell v
    with octile(s, v) + octile(v, g) <= limit. For a fixed first coordinate the sum is convex and
    piecewise linear in the second, so its minimum lies at one of the breakpoints."""
    u = np.arange(n, dtype=np.float64)[:, None]
    (su, sv), (gu, gv) = s, g
    cand = np.hstack([np.full_like(u, sv), np.full_like(u, gv), sv + np.abs(u - su), sv - np.abs(u - su),
                      gv + np.abs(u - gu), gv - np.abs(u - gu)]).clip(0, m - 1)
    lb = (_octile(cand - sv, u - su) + _octile(gv - cand, gu - u)).min(axis=1)
    inside = np.flatnonzero(lb <= limit)
    return (int(inside[0]), int(inside[-1]) + 1) if len(inside) else (su, su + 1)


def search_window(shape, s: tuple[int, int], g: tuple[int, int], limit: float) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1): the rows and columns that hold every cell v (x, y) with
    octile(s, v) + octile(v, g) <= limit, i.e. every cell an A* search with f <= limit can expand."""
    (sx, sy), (gx, gy) = s, g
    y0, y1 = _extent(shape[0], shape[1], (sy, sx), (gy, gx), limit)
    x0, x1 = _extent(shape[1], shape[0], (sx, sy), (gx, gy), limit)
    return y0, y1, x0, x1


def _heuristic(graph: GridGraph, g: int, tables: np.ndarray | None, y0: int, y1: int, x0: int, x1: int) -> np.ndarray:
    """Admissible, consistent h to the goal on the window [y0, y1) x [x0, x1): octile distance,
    raised by the ALT landmark bounds (less their float32 rounding)."""
    h_rows, w = graph.shape
    gy, gx = divmod(g, w)
    h = _octile(np.arange(x0, x1, dtype=np.float64)[None, :] - gx, np.arange(y0, y1, dtype=np.float64)[:, None] - gy)
    if tables is not None and len(tables):
        win = tables.reshape(len(tables), h_rows, w)[:, y0:y1, x0:x1]
        alt = np.abs(win[0] - tables[0, g])
        for t, tg in zip(win[1:], tables[1:, g]):
            np.maximum(alt, np.abs(t - tg), out=alt)
        alt -= ALT_ROUNDING
        np.fmax(h, alt, out=h)  # inf off the goal's component: never reached
    return h


_STEPS = np.array([(dy, dx) for dy, dx, _ in OFFSETS8])


def _window_search(graph: GridGraph, s: int, g: int, tables, limit: float, win) -> np.ndarray | None:
    """Dijkstra on reduced costs w - h(u) + h(v) (A*'s expansion order) inside the window, expanding
    nodes with f <= h(s) + limit; the path's cells, or None when the goal is not settled."""
    y0, y1, x0, x1 = win
    h_rows, w = graph.shape
    r, c = y1 - y0, x1 - x0
    # h on the window and one cell around it (the targets of its edges), 0 off the map
    hp = np.zeros((r + 2, c + 2))
    a, b, e, f = max(0, y0 - 1), min(h_rows, y1 + 1), max(0, x0 - 1), min(w, x1 + 1)
    hp[a - y0 + 1:b - y0 + 1, e - x0 + 1:f - x0 + 1] = _heuristic(graph, g, tables, a, b, e, f)
    hc = hp[1:-1, 1:-1]
    base = {1.0: hc - 1.0, SQRT2: hc - SQRT2}
    data = np.empty((r, c, 8))
    with np.errstate(invalid="ignore"):
        for k, (dy, dx, cost) in enumerate(OFFSETS8):
            np.subtract(hp[1 + dy:r + 1 + dy, 1 + dx:c + 1 + dx], base[cost], out=data[:, :, k])
        data = data.reshape(-1)
        np.fmax(data, 1e-9, out=data)  # nan (inf - inf) only off the goal's component
    moves = graph.moves[y0:y1, x0:x1].copy()
    moves[0, :, _STEPS[:, 0] < 0] = False  # no move leaves the window
    moves[-1, :, _STEPS[:, 0] > 0] = False
    moves[:, 0, _STEPS[:, 1] < 0] = False
    moves[:, -1, _STEPS[:, 1] > 0] = False
    n = r * c
    local = np.arange(n, dtype=np.int32).reshape(r, c, 1)
    idx = np.where(moves, local + (_STEPS[:, 0] * c + _STEPS[:, 1]).astype(np.int32), local).reshape(-1)
    gr = sparse.csr_matrix((data, idx, np.arange(0, 8 * n + 1, 8, dtype=np.int32)), shape=(n, n))
    (sy, sx), (gy, gx) = divmod(s, w), divmod(g, w)
    s_l, g_l = (sy - y0) * c + sx - x0, (gy - y0) * c + gx - x0
    dist, pred = csgraph.dijkstra(gr, indices=s_l, return_predecessors=True, limit=limit)
    if not np.isfinite(dist[g_l]):
        return None
    cells = path_cells(pred, s_l, g_l, c)  # window (x, y) -> map (x, y)
    cells += (x0, y0)
    return cells


def astar_path(graph: GridGraph, s: int, g: int, landmarks: np.ndarray | None = None) -> np.ndarray | None:
    """A* with the octile heuristic (tightened by ALT landmark bounds when tables are given: still
    admissible and consistent), run as Dijkstra on reduced costs w - h(u) + h(v) >= 0, which expands
    nodes in A*'s order, under a bound on f: only nodes with f <= h(s) + limit are expanded, and only
    the window of rows and columns that can hold them is built. The limit starts small and grows
    until the goal is settled; it never needs to exceed the length of the path through the best
    landmark. Returns the cells (x, y) of a shortest 8-connected path, or None."""
    if graph.component[s] != graph.component[g]:
        return None
    w = graph.shape[1]
    tables, cap = None, math.inf
    if landmarks is not None and len(landmarks):
        tables = landmarks[np.isfinite(landmarks[:, g])]  # those in the goal's component
        if len(tables):  # d(s, g) <= d(s, L) + d(L, g): a path through landmark L
            cap = float(np.min(tables[:, s].astype(np.float64) + tables[:, g]))
    (sy, sx), (gy, gx) = divmod(s, w), divmod(g, w)
    h_s = float(_heuristic(graph, g, tables, sy, sy + 1, sx, sx + 1)[0, 0])
    cap = cap - h_s + 0.1 if math.isfinite(cap) else math.inf  # + float32 rounding, generously
    limit = min(0.5 + 0.01 * h_s, cap)
    while True:
        win = search_window(graph.shape, (sx, sy), (gx, gy), h_s + limit + 1e-6)
        cells = _window_search(graph, s, g, tables, limit, win)
        if cells is not None:
            return cells
        if limit >= cap:  # not with exact landmark tables; the full graph settles it
            return dijkstra_path(graph, s, g)
        limit = min(limit * 4.0, cap)


# ---------- smoothing ----------

def segment_free(free: np.ndarray, a, b, step: float = 0.5) -> bool:
    return bool(segments_free(free, np.asarray(a, float), np.asarray([b], float), step)[0])


def _sight(free: np.ndarray, ax, ay, d: np.ndarray, step: float) -> np.ndarray:
    """Line of sight from (ax, ay) along each row of d: the cell of every sample, taken every `step`
    cells, is on the map and free."""
    n = int(np.ceil(np.sqrt(np.max(d[:, 0] ** 2 + d[:, 1] ** 2, initial=0.0)) / step)) + 1
    t = np.linspace(0.0, 1.0, n + 1)
    px = np.rint(ax + d[:, :1] * t)
    py = np.rint(ay + d[:, 1:] * t)
    h, w = free.shape
    inside = (px >= 0) & (px <= w - 1) & (py >= 0) & (py <= h - 1)
    inside &= free[py.clip(0, h - 1).astype(np.intp), px.clip(0, w - 1).astype(np.intp)]
    return inside.all(axis=1)


def segments_free(free: np.ndarray, a: np.ndarray, bs: np.ndarray, step: float = 0.25) -> np.ndarray:
    """Line of sight from point a to each of bs (cell coordinates): every sample's cell is free.

    Samples every quarter cell: a segment may clip the corner of an occupied cell of the *inflated*
    map by at most ~0.1 cell, never the obstacle itself (inflation is at least the robot's radius)."""
    return _sight(free, a[0], a[1], bs - a, step)


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
    return _sight(free, a[:, :1], a[:, 1:], b - a, step)


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
