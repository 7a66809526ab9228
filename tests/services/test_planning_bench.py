"""The planning benchmark's rows on one map (one round, short OMPL budget): every planner measured
on every start/goal pair, the floor taken from an optimal peer, path lengths against the any-angle
optimum (times are not judged here: the machine is shared)."""
import pytest

from bench import planning as bench_planning


def test_generated_house_rows():
    rows, maps = bench_planning.measure(repeats=1, ompl_time=0.2, maps=["generated"])
    (bm,) = maps
    assert len(bm.queries) >= 3 and len(bm.refs) == len(bm.queries)
    by_name = {r["name"]: r for r in rows}
    planners = ["astar", "astar_raw", "scipy_dijkstra", "dijkstra", "bitstar", "rrtconnect"]
    assert set(by_name) == {"plan_astar"} | {f"plan_{p}_generated" for p in planners}
    astar = by_name["plan_astar_generated"]
    peers = [by_name[f"plan_{p}_generated"] for p in bench_planning.OPTIMAL_PEERS]
    assert astar["floor"] == pytest.approx(min(p["median"] for p in peers), rel=1e-3)
    assert astar["ratio"] == pytest.approx(astar["median"] / astar["floor"], rel=1e-2)
    for r in rows:
        assert r["n"] == len(r["values"]) >= len(bm.queries)
    # the reference is the any-angle optimum: the grid planners' raw paths are 8-connected (longer),
    # the smoothed ones pulled taut to within the goal
    assert 1.0 < by_name["plan_scipy_dijkstra_generated"]["length_ratio"] < 1.09
    assert 0.99 < astar["length_ratio"] <= 1.02
    assert by_name["plan_astar"]["worst_map"] == "generated"


def test_reference_is_between_the_straight_line_and_the_grid_path():
    import numpy as np

    from agents.services import planning

    free = np.ones((30, 40), bool)
    free[10:20, 18:22] = False  # a block between the ends of the second pair
    assert bench_planning.reference_length(free, (2, 5), (37, 5)) == pytest.approx(35.0, abs=1e-6)
    around = bench_planning.reference_length(free, (2, 15), (37, 15))
    graph = planning.GridGraph(free)
    grid = planning.path_length(planning.dijkstra_path(graph, graph.node(2, 15), graph.node(37, 15)))
    assert 35.0 + 1.0 < around < grid - 1.0  # detours, but cuts the 8-connected path's corners
