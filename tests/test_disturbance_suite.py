"""The disturbance suite (scenarios/disturbance_suite.py): the hazard RApp in the two-door house against
things that move. Every whole case is slow-marked, the fast one too (all of them:
`rapp run disturbances`, docs/disturbances.md)."""
from __future__ import annotations

import pytest

from agents.tracing import read_trace
from scenarios.disturbance_suite import CASES, FAST, judge, run_case, table


def result(**kw) -> dict:
    base = {"robot": "nao", "finished": True, "all_correct": True, "routes_blocked": [], "person_contacts": 0,
            "object_contacts": 0, "strategies": [], "replans": 0, "obstacles_marked": 0, "estops": 0,
            "duration_sim_s": 1.0, "duration_wall_s": 1.0, "trace": "t"}
    return {**base, **kw}


def test_a_case_passes_only_finished_correct_and_without_touching_anyone():
    case = CASES["door-closed"]
    assert judge(case, result())["passed"]
    assert not judge(case, result(person_contacts=1))["passed"]
    assert not judge(case, result(all_correct=False))["passed"]
    assert not judge(case, result(finished=False))["passed"]
    # a route reported blocked where another door was open is wrong
    assert not judge(case, result(routes_blocked=[{"id": "route-l_bed", "blocked_by": ["door d_north"]}]))["passed"]


def test_the_only_route_case_needs_both_closed_doors_reported():
    case = CASES["only-route-closed"]
    both = [{"id": "route-l_bed", "blocked_by": ["door d_north", "door d_south"]}]
    assert judge(case, result(all_correct=False, routes_blocked=both))["passed"]
    assert not judge(case, result(all_correct=False, routes_blocked=both[:0]))["passed"]
    one = [{"id": "route-l_bed", "blocked_by": ["door d_north"]}]
    assert not judge(case, result(all_correct=False, routes_blocked=one))["passed"]
    assert "| only-route-closed | nao | yes | yes | 0 | 0 |" in table([judge(case, result(routes_blocked=both))])


# slow-marked for the default suite's time (80 s of one worker): the plan monitor's block, mark and
# re-plan are in test_strategies by default, the whole run with `pytest -m slow` and `rapp run disturbances`
@pytest.mark.slow
@pytest.mark.timeout(400)
@pytest.mark.parametrize("name", FAST)
async def test_fast_case_on_the_elektron(name, tmp_path):
    """The north door is closed on the robot's way: blocked, the door entered into the map, re-planned
    through the south door, the lamp checked; nobody touched."""
    row = await run_case(CASES[name], "elektron", out_dir=tmp_path)
    assert row["passed"], row
    assert row["replans"] >= 1 and row["obstacles_marked"] >= 1
    marked = [r for r in read_trace(row["trace"]) if r["kind"] == "structure" and r["event"] == "obstacle-marked"]
    assert any(3.2 < r["x"] < 3.8 and 2.6 < r["y"] < 3.7 for r in marked), marked  # in the north doorway


@pytest.mark.slow
@pytest.mark.timeout(900)
@pytest.mark.parametrize("name, robot", [("only-route-closed", "elektron"), ("person-standing", "nao"),
                                         ("estop-resume", "elektron"), ("box-in-doorway", "nao")])
async def test_slow_cases(name, robot, tmp_path):
    row = await run_case(CASES[name], robot, out_dir=tmp_path)
    assert row["passed"], row
