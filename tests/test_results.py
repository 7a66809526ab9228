"""Results as data (issue 44 item 4; issue 43 items 4 and 7): the task record's size budget, one world
per seed in every scenario, and a long run's plain progress lines folded."""
from __future__ import annotations

import ast
import re
from pathlib import Path

from ontology.results import ReportRecord, TaskRecord, TaskStage
from scenarios.home_setup import hazard_overrides, scenario_world
from scenarios.progress import PlainLines

ROOT = Path(__file__).resolve().parent.parent


def test_a_record_too_large_for_one_message_leaves_out_its_earliest_reports():
    reports = [ReportRecord(text=f"report {i}", data={"blob": "x" * 1000}, stamp=float(i)) for i in range(300)]
    record = TaskRecord(robot_id="nao1", rapp="r", stage=TaskStage.RUN, state="Finished", ok=True, reports=reports,
                        ended=1.0)
    fitted = record.fitted(budget=50_000)
    assert len(fitted.model_dump_json()) <= 50_000
    assert fitted.reports == reports[-len(fitted.reports):] and fitted.reports_omitted == 300 - len(fitted.reports)
    assert 40 < len(fitted.reports) < 50
    small = record.model_copy(update={"reports": reports[:3]})
    assert small.fitted(budget=50_000) is small  # nothing to leave out


def test_the_same_seed_draws_the_same_world_in_every_scenario():
    """"full house, seed 1" was one world under hazard-detection (its overrides) and another under
    `rapp run rapp` (the house file's ranges): every scenario now builds its world with scenario_world."""
    for house in ("small", "house", "twodoors"):
        for seed in (1, 2):
            world = scenario_world(house, seed)
            try:
                truth = world.ground_truth()
            finally:
                world.close()
            drawn = hazard_overrides(house, seed)
            assert {d: truth.doors[d] for d in drawn["doors"]} == drawn["doors"]
            assert {lp: truth.lamps[lp] for lp in drawn["lamps"]} == drawn["lamps"]
    for module in ("run_rapp", "hazard", "two_robots"):  # none builds a world of its own
        tree = ast.parse((ROOT / "scenarios" / f"{module}.py").read_text())
        calls = {n.func.attr if isinstance(n.func, ast.Attribute) else getattr(n.func, "id", "")
                 for n in ast.walk(tree) if isinstance(n, ast.Call)}
        assert "scenario_world" in calls and "from_file" not in calls, module


def state(fsm: str, name: str, agent: str = "dyn-x@localhost") -> dict:
    return {"kind": "state", "event": "enter", "agent": agent, "fsm": fsm, "state": name}


def progress(fraction: float, text: str) -> dict:
    return {"kind": "progress", "agent": "dyn-x@localhost", "fraction": fraction, "text": text}


def test_plain_lines_fold_a_walks_steps_and_give_their_totals():
    lines: list[str] = []
    plain = PlainLines(lines.append, status_every=30.0)
    plain.batch([state("core", "s4a_keyword", "core-nao1@localhost"), state("core", "s5_download", "core-nao1@localhost"),
                 {"kind": "structure", "event": "spawn", "agent": "core-nao1@localhost", "dynamic": "dyn-x@localhost"},
                 state("hazard", "s4_go"), progress(0.25, "d1: on the way")], now=0.0)
    plain.status(0.0, (1.0, 2.0, 0.5))
    for i in range(200):  # a long walk: re-localizing every few decimetres
        plain.batch([state("navigate", "n3_relocalize"), state("n3_relocalize", "l3_capture"),
                     progress(0.25, f"d1: at ({i / 10:.2f}, 2.00), 0% of the path")], now=i * 0.5)
        plain.status(i * 0.5, (i / 10, 2.0, 0.0))
    plain.batch([state("hazard", "s5_check"), progress(0.5, "d2: on the way")], now=100.0)
    assert lines[0] == "core: s4a_keyword -> s5_download"  # one read's Core states, one line
    assert "rapp hazard: s4_go" in lines and "rapp hazard: s5_check" in lines
    assert "progress dyn-x: 25% d1: on the way" in lines and "progress dyn-x: 50% d2: on the way" in lines
    assert not [line for line in lines if "l3_capture" in line or "% of the path" in line and "folded" not in line]
    status = [line for line in lines if "steps folded" in line]
    assert len(status) == 3 and "latest: d1: at (" in status[-1]  # one every 30 s of the 100 s
    assert len(lines) < 15, lines
    assert plain.totals() == ["navigate 200 (n3_relocalize 200)", "n3_relocalize 200 (l3_capture 200)"]


async def test_a_run_that_does_not_end_in_time_says_where_it_stands(tmp_path):
    """`rapp run rapp --timeout`: the reason said "nao: no end within 3 s" and nothing of where the run was."""
    from scenarios.run_rapp import run_rapp

    from .test_lifecycle import variant

    src = variant(tmp_path, "silent-echo", "silentecho", behaviour="silent")
    result = await run_rapp(src, "nao", "small", 1, None, tmp_path / "run", timeout_s=3)
    assert not result["ok"]
    assert re.fullmatch(r"nao: no end within 3 s: the Core in s\d+\w*; silent-echo (Spawned|Init|Working), no report "
                        r"yet", result["reason"]), result["reason"]
