"""A* (searched in a window of the grid, under a growing bound on f) finds paths exactly as short
as a full Dijkstra, on random cluttered grids and on the houses the benchmark plans in."""
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from scipy.sparse import csgraph

from agents.services import navigation, planning
from agents.services.maps import GridMap


def _valid_path(graph: planning.GridGraph, cells: np.ndarray) -> bool:
    """Every step an edge of the 8-connected graph (free cells, no corner cutting)."""
    xs, ys = cells[:, 0].astype(int), cells[:, 1].astype(int)
    if not graph.free[ys, xs].all():
        return False
    for (x0, y0), (x1, y1) in zip(zip(xs, ys), zip(xs[1:], ys[1:])):
        dx, dy = x1 - x0, y1 - y0
        if max(abs(dx), abs(dy)) != 1 or (dx and dy and not (graph.free[y0, x1] and graph.free[y1, x0])):
            return False
    return True


def _check_pairs(graph, landmarks, pairs):
    for s, g in pairs:
        dist = csgraph.dijkstra(graph.csr, indices=s)
        path = planning.astar_path(graph, s, g, landmarks)
        if not np.isfinite(dist[g]):
            assert path is None
            continue
        assert path is not None and _valid_path(graph, path)
        assert tuple(path[0]) == divmod(s, graph.shape[1])[::-1] and tuple(path[-1]) == divmod(g, graph.shape[1])[::-1]
        assert planning.path_length(path) == pytest.approx(dist[g], abs=1e-6)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), density=st.floats(0.05, 0.35), use_landmarks=st.booleans())
def test_astar_is_as_short_as_dijkstra_on_random_grids(seed, density, use_landmarks):
    rng = np.random.default_rng(seed)
    blocked = rng.random((40, 60)) < density
    blocked[rng.integers(0, 40), :] |= rng.random(60) < 0.8  # walls with gaps: long detours
    graph = planning.GridGraph(~blocked)
    landmarks = planning.landmark_distances(graph, 4) if use_landmarks else None
    free = np.flatnonzero(~blocked)
    pairs = [tuple(int(v) for v in rng.choice(free, 2)) for _ in range(6)]
    _check_pairs(graph, landmarks, pairs)


def test_search_window_holds_every_cell_within_the_bound():
    rng = np.random.default_rng(3)
    h, w = 30, 50
    ys, xs = np.mgrid[0:h, 0:w]
    for _ in range(40):
        s, g = (int(rng.integers(w)), int(rng.integers(h))), (int(rng.integers(w)), int(rng.integers(h)))
        limit = planning._octile(s[0] - g[0], s[1] - g[1]) + float(rng.uniform(0, 20))
        lb = planning._octile(xs - s[0], ys - s[1]) + planning._octile(g[0] - xs, g[1] - ys)
        inside = lb <= limit
        y0, y1, x0, x1 = planning.search_window((h, w), s, g, limit)
        assert inside.sum() == inside[y0:y1, x0:x1].sum()
        assert inside[y0].any() and inside[y1 - 1].any() and inside[:, x0].any() and inside[:, x1 - 1].any()


@pytest.mark.parametrize("build", ["full_house", "generated_house", "open_hall"])
def test_astar_is_as_short_as_dijkstra_on_the_benchmark_maps(build):
    from bench import planning as bench_planning

    bm = getattr(bench_planning, build)()
    m: GridMap = bm.grid
    graph = navigation.grid_graph(m, "elektron")
    landmarks = navigation.landmarks(m, "elektron")
    rng = np.random.default_rng(7)
    free = np.flatnonzero(graph.free.reshape(-1))
    pairs = [(graph.node(*s), graph.node(*g)) for s, g in bm.queries]
    pairs += [tuple(int(v) for v in rng.choice(free, 2)) for _ in range(4)]
    _check_pairs(graph, landmarks, pairs)
