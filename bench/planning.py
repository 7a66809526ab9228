"""Path planning against optimal peers on three maps: the full house, a generated house and an open hall.

    python -m bench.planning [--repeats N] [--ompl-time S] [--json-only]

Per map, several start/goal pairs (elektron's cost map, 5 cm cells), every planner timed on each pair
in interleaved rounds (so load on a shared machine falls on all of them alike), at least 20 samples
per planner and map:

- plan_astar_<map>: the project's A* as the navigation service runs it (search, corners, smoothing);
  ratio = its median / the fastest optimal peer's median on that map (the floor), length_ratio =
  worst path length / the optimal length over the map's pairs. Goal: ratio <= 1, length <= 1.02.
- optimal peers: scipy_dijkstra (scipy.sparse.csgraph.dijkstra on the same 8-connected graph, raw
  grid path), dijkstra (the project's Dijkstra with the same smoothing as A*), bitstar (OMPL BIT*,
  asymptotically optimal, spends its whole time budget: one run per pair, two with --repeats >= 5).
- context: astar_raw (the search alone, no smoothing) and rrtconnect (OMPL RRTConnect: randomized,
  not optimal; its length ratio says what its speed buys).

The optimal length is an any-angle reference: Dijkstra over all coprime offsets up to 4 cells whose
segment is free (overestimates by < 0.5 %), then tightened by line-of-sight cuts. plan_astar (no map
suffix) is the worst map's row, the one the runner judges against the goal. Per-map tables (cost
map, graph, ALT landmarks) are built before the timing, as the service builds them once per map
(their time is the astar row's prep_ms).
"""
from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, field
from math import gcd

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from .common import fmt, median, metric

RES = 0.05
SIZE = 400
ROBOT = "elektron"
GENERATED_SEED = 14  # 8 rooms, 13.5 m x 13 m, 15 pieces of furniture
HOUSE_SEED = 1  # passage door angle of the full house (scenarios.home_setup.hazard_overrides)
MIN_SAMPLES = 20  # per planner and map
OPTIMAL_PEERS = ("scipy_dijkstra", "dijkstra", "bitstar")
TIMED = ("scipy_dijkstra", "dijkstra", "astar", "astar_raw", "rrtconnect")  # interleaved per pair


def make_house(size: int = SIZE, res: float = RES) -> np.ndarray:
    """blocked[iy, ix] of a synthetic 4-room house with 0.9 m doors, a corridor and furniture
    (tests/services/test_navigation.py plans on it)."""
    b = np.zeros((size, size), bool)
    t = int(0.15 / res)  # wall thickness

    def box(x0, y0, x1, y1):  # metres
        b[int(y0 / res):int(math.ceil(y1 / res)), int(x0 / res):int(math.ceil(x1 / res))] = True

    def clear(x0, y0, x1, y1):
        b[int(y0 / res):int(math.ceil(y1 / res)), int(x0 / res):int(math.ceil(x1 / res))] = False

    wall = t * res
    for rect in ((0, 0, 20, wall), (0, 20 - wall, 20, 20), (0, 0, wall, 20), (20 - wall, 0, 20, 20)):
        box(*rect)
    box(9, 0, 9 + wall, 20)           # west | east
    box(0, 10, 9, 10 + wall)          # west rooms split
    box(9, 12, 20, 12 + wall)         # east: living room / corridor-bedrooms
    box(14.5, 12, 14.5 + wall, 20)    # two bedrooms north-east
    box(9, 6, 20, 6 + wall)           # kitchen south-east
    for x0, y0, x1, y1 in [(3.5, 10, 4.4, 10.2), (9, 3, 9.2, 3.9), (9, 15, 9.2, 15.9),
                           (11, 12, 11.9, 12.2), (17, 12, 17.9, 12.2), (15, 6, 15.9, 6.2)]:
        clear(x0 - 0.01, y0 - 0.01, x1 + 0.01, y1 + 0.01)  # doors 0.9 m
    for f in [(1, 1, 3, 2.2), (5, 3, 7, 4), (2, 14, 3.5, 18), (6, 12, 8, 13), (11, 8, 13, 10.5),
              (16, 8, 19, 9), (10, 17.5, 13, 19.5), (16, 15, 18, 16.5), (12, 1, 14, 3.5),
              (17, 1, 19.5, 2)]:
        box(*f)  # furniture
    return b


# ---------- the maps ----------

@dataclass
class BenchMap:
    name: str
    grid: object  # agents.services.maps.GridMap
    queries: list[tuple[tuple[float, float], tuple[float, float]]]  # (start, goal) in cell coordinates
    note: str = ""
    refs: list[float] = field(default_factory=list)  # optimal length per query (cells)


def _platform_map(name: str, plan, house: str):
    """The map as the Platform holds it after the owner's upload (scenarios.home_setup.home_map:
    walls, furniture, lamps, passage doors drawn open)."""
    from agents.services.maps import GridMap, grid_from_image
    from scenarios.home_setup import home_map

    img = home_map(plan, house)
    return GridMap(name, grid_from_image(img.image), img.resolution, tuple(img.origin))


def _room_queries(m, plan) -> list:
    """Room centre i to room centre i + n/2 (up to 4 pairs), each snapped to the nearest free cell
    of the robot's cost map; pairs in different components are left out."""
    from agents.services import navigation

    graph = navigation.grid_graph(m, ROBOT)
    centres = []
    for r in plan.rooms:
        x0, y0, x1, y1 = r.rect
        c, _ = navigation.nearest_free(m, ROBOT, 0.0, m.world_to_cell((x0 + x1) / 2, (y0 + y1) / 2))
        centres.append((int(c[0]), int(c[1])))
    n = len(centres)
    out = []
    for i in range(min(n, 4)):
        s, g = centres[i], centres[(i + n // 2) % n]
        if s != g and graph.component[graph.node(*s)] == graph.component[graph.node(*g)]:
            out.append((s, g))
    return out


def full_house():
    from robots.floorplan import load_plan
    from robots.world import HOUSES
    from scenarios.home_setup import hazard_overrides

    plan = load_plan(HOUSES / "house.yaml", HOUSE_SEED, hazard_overrides("house", HOUSE_SEED))
    m = _platform_map("house", plan, "house")
    return BenchMap("house", m, _room_queries(m, plan), "robots/houses/house.yaml, 20 m x 20 m")


def generated_house(seed: int = GENERATED_SEED):
    from robots.floorplan import load_plan
    from robots.house_gen import GENERATED, generate
    from scenarios.home_setup import hazard_overrides

    plan = load_plan(generate(seed), seed, hazard_overrides(GENERATED, seed))
    m = _platform_map("generated", plan, GENERATED)
    return BenchMap("generated", m, _room_queries(m, plan), f"robots/house_gen.py seed {seed}")


def open_hall(w_m: float = 30.0, h_m: float = 20.0):
    """A 30 m x 20 m hall: outer walls and 0.4 m pillars every 5 m; corner-to-corner and across."""
    from agents.services.maps import GridMap

    w, h = int(round(w_m / RES)), int(round(h_m / RES))
    b = np.zeros((h, w), bool)
    b[:3, :] = b[-3:, :] = True
    b[:, :3] = b[:, -3:] = True
    p = int(round(0.4 / RES))
    for x in np.arange(5.0, w_m - 1, 5.0):
        for y in np.arange(5.0, h_m - 1, 5.0):
            cx, cy = int(x / RES), int(y / RES)
            b[cy - p // 2:cy + p // 2, cx - p // 2:cx + p // 2] = True
    m = GridMap("hall", b, RES, (0.0, 0.0, 0.0))
    c = lambda x, y: (int(round(x / RES - 0.5)), int(round(y / RES - 0.5)))  # noqa: E731
    queries = [(c(1, 1), c(29, 19)), (c(1, 19), c(29, 1)), (c(1, 10.2), c(29, 9.8)), (c(14.6, 1), c(15.4, 19))]
    return BenchMap("hall", m, queries, f"{w_m:g} m x {h_m:g} m, pillars every 5 m")


MAP_BUILDERS = {"house": full_house, "generated": generated_house, "hall": open_hall}


# ---------- the optimal reference ----------

def reference_graph(free: np.ndarray, radius: int = 4):
    """Any-angle reference graph: every coprime offset up to `radius` whose segment is free (the
    cells it passes through, with a small tolerance either side)."""
    from agents.services import planning

    h, w = free.shape
    idx = np.arange(h * w, dtype=np.int32).reshape(h, w)
    padded = np.pad(free, radius, constant_values=False)
    rows, cols, wts = [], [], []
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            if (dx, dy) == (0, 0) or gcd(abs(dx), abs(dy)) != 1:
                continue
            touched = set()
            for tt in np.linspace(0, 1, 64 * radius):  # cells the segment passes through
                for ex in (-0.01, 0.01):
                    for ey in (-0.01, 0.01):
                        touched.add((int(round(tt * dy + ey)), int(round(tt * dx + ex))))
            ys, xs = planning.source_cells(dy, h), planning.source_cells(dx, w)
            ok = free[ys, xs].copy()
            for ty, tx in touched:
                ok &= padded[radius + ty:radius + ty + h, radius + tx:radius + tx + w][ys, xs]
            rows.append(idx[ys, xs][ok])
            cols.append(idx[planning.target_cells(dy, h), planning.target_cells(dx, w)][ok])
            wts.append(np.full(int(ok.sum()), math.hypot(dx, dy)))
    return sparse.csr_matrix((np.concatenate(wts), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(h * w,) * 2)


def reference_length(free: np.ndarray, s, g, graph=None) -> float:
    """Optimal length (cells) from cell s to cell g: the reference graph's shortest path, tightened
    by line-of-sight cuts; the shorter of the two."""
    from agents.services import planning

    graph = reference_graph(free) if graph is None else graph
    w = free.shape[1]
    si, gi = s[1] * w + s[0], g[1] * w + g[0]
    dist, pred = csgraph.dijkstra(graph, indices=si, return_predecessors=True)
    pts = planning.path_cells(pred, si, gi, w)
    tight = planning.tighten(free, planning.shortcut(free, pts), rounds=10)
    return min(float(dist[gi]), planning.path_length(tight))


# ---------- the measurement ----------

def _runners(m, ompl_time: float) -> dict:
    from agents.services import navigation, planning

    graph = navigation.grid_graph(m, ROBOT)
    landmarks = navigation.landmarks(m, ROBOT)

    def scipy_dijkstra(s, g):  # the raw library: full single-source Dijkstra, then the grid path
        si, gi = graph.node(*s), graph.node(*g)
        dist, pred = csgraph.dijkstra(graph.csr, indices=si, return_predecessors=True)
        return planning.path_cells(pred, si, gi, graph.shape[1])

    return {
        "scipy_dijkstra": scipy_dijkstra,
        "dijkstra": lambda s, g: navigation.plan_cells(m, ROBOT, "dijkstra", s, g, 0),
        "astar": lambda s, g: navigation.plan_cells(m, ROBOT, "astar", s, g, 0),
        "astar_raw": lambda s, g: planning.astar_path(graph, graph.node(*s), graph.node(*g), landmarks),
        "rrtconnect": lambda s, g: navigation.plan_cells(m, ROBOT, "rrtconnect", s, g, ompl_time),
        "bitstar": lambda s, g: navigation.plan_cells(m, ROBOT, "bitstar", s, g, ompl_time),
    }


def _timed(fn, s, g) -> tuple[float, object]:
    t0 = time.perf_counter()
    pts = fn(s, g)
    return time.perf_counter() - t0, pts


def measure_map(bm: BenchMap, rounds: int, ompl_time: float, bitstar_runs: int = 1) -> tuple[dict, float]:
    """({planner: (times s, length ratios)}, per-map preparation s) on one map. Per-map tables
    (cost map, graph, ALT landmarks) are built before the timing, as the service builds them once
    per map; the preparation is one fresh build of graph and landmark tables, timed apart."""
    from agents.services import navigation, planning

    free = navigation.free_cells(bm.grid, ROBOT)
    t0 = time.perf_counter()
    planning.landmark_distances(planning.GridGraph(free))
    prep = time.perf_counter() - t0
    ref_graph = reference_graph(free)
    bm.refs = [reference_length(free, s, g, ref_graph) for s, g in bm.queries]
    runners = _runners(bm.grid, ompl_time)
    out = {name: ([], []) for name in runners}

    def record(name, k, dt, pts):
        out[name][0].append(dt)
        out[name][1].append(planning.path_length(pts) / bm.refs[k] if pts is not None else math.inf)

    for k, (s, g) in enumerate(bm.queries):  # warm-up: first calls build per-map caches, load OMPL
        for name in TIMED:
            runners[name](s, g)
    for _ in range(rounds):
        for k, (s, g) in enumerate(bm.queries):
            for name in TIMED:
                record(name, k, *_timed(runners[name], s, g))
    for _ in range(bitstar_runs):
        for k, (s, g) in enumerate(bm.queries):
            record("bitstar", k, *_timed(runners["bitstar"], s, g))
    return out, prep


def map_metrics(bm: BenchMap, res: dict, prep_s: float, ompl_time: float) -> list[dict]:
    meds = {name: median(ts) for name, (ts, _) in res.items()}
    peer = min(OPTIMAL_PEERS, key=meds.__getitem__)
    floor = meds[peer]
    rows = []
    for name in ("astar", "astar_raw", "scipy_dijkstra", "dijkstra", "bitstar", "rrtconnect"):
        ts, lens = res[name]
        extra = {"peer": name in OPTIMAL_PEERS, "map": bm.name, "floor_peer": peer,
                 "length_ratio": max(lens), "length_ratio_median": median(lens)}
        if name == "astar":
            extra["prep_ms"] = prep_s * 1e3  # graph and ALT tables, built once per map
        if name in ("bitstar", "rrtconnect"):
            extra["ompl_time_s"] = ompl_time
        samples = [round(t * 1e3, 3) for t in ts]
        rows.append(metric(f"plan_{name}_{bm.name}", meds[name] * 1e3, "ms", floor * 1e3,
                           meds[name] / floor, len(ts), samples=samples, values=samples, **extra))
    return rows


def measure(repeats: int = 5, ompl_time: float = 1.0, maps=None) -> tuple[list[dict], list[BenchMap]]:
    """Metrics of every map plus plan_astar (the worst map's row). `repeats` rounds over a map's
    pairs, raised to MIN_SAMPLES samples per planner; repeats=1 is a smoke run (one round)."""
    rows, done = [], []
    for name in maps or MAP_BUILDERS:
        bm = MAP_BUILDERS[name]()
        n = len(bm.queries)
        rounds = 1 if repeats <= 1 else max(repeats, math.ceil(MIN_SAMPLES / n))
        res, prep_s = measure_map(bm, rounds, ompl_time, bitstar_runs=2 if repeats >= 5 else 1)
        rows += map_metrics(bm, res, prep_s, ompl_time)
        done.append(bm)
    astar = [r for r in rows if r["name"].startswith("plan_astar_") and not r["name"].startswith("plan_astar_raw")]
    worst = max(astar, key=lambda r: (r["ratio"] > 1.0 or r["length_ratio"] > 1.02, r["ratio"]))
    summary = dict(worst, name="plan_astar", worst_map=worst["map"],
                   length_ratio=max(r["length_ratio"] for r in astar),
                   ratio_per_map={r["map"]: r["ratio"] for r in astar})
    return [summary] + rows, done


def report(rows: list[dict], maps: list[BenchMap]) -> str:
    lines = [f"{bm.name}: {bm.grid.width}x{bm.grid.height} cells @ {RES} m ({bm.note}), robot {ROBOT}, "
             f"{len(bm.queries)} start/goal pairs, optimal lengths (m): {[round(r * RES, 2) for r in bm.refs]}"
             for bm in maps]
    cols = ["name", "median", "p95", "floor", "ratio", "length_ratio", "n", "floor_peer"]
    shown = [{c: r.get(c) for c in cols} for r in rows]
    cells = [cols] + [[fmt(v) for v in row.values()] for row in shown]
    widths = [max(len(c[i]) for c in cells) for i in range(len(cols))]
    lines += ["  ".join(v.ljust(wd) if i in (0, 7) else v.rjust(wd) for i, (v, wd) in enumerate(zip(c, widths)))
              for c in cells]
    return "\n".join(lines)


def run(repeats: int = 5, ompl_time: float = 1.0, json_only: bool = False) -> list[dict]:
    """The metrics, each with `values` (its samples, ms) for the runner, plus a plan_scipy_dijkstra
    row (the scipy peer on plan_astar's map), from which the runner takes its floor."""
    import json

    rows, maps = measure(repeats, ompl_time)
    scipy = next(r for r in rows if r["name"] == f"plan_scipy_dijkstra_{rows[0]['map']}")
    rows.append(dict(scipy, name="plan_scipy_dijkstra"))
    if not json_only:
        print(report(rows, maps))
    for r in rows:
        print(json.dumps({k: v for k, v in r.items() if k != "values"}))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="rounds over each map's pairs (at least 20 samples)")
    ap.add_argument("--ompl-time", type=float, default=1.0, help="OMPL time budget (s), BIT* spends all of it")
    ap.add_argument("--json-only", action="store_true")
    a = ap.parse_args()
    run(a.repeats, a.ompl_time, a.json_only)


if __name__ == "__main__":
    main()
