"""Runs lamp-patrol on the simulated robots, as `rapp run rapp rapps/examples/lamp_patrol` does."""
import json
from pathlib import Path

import pytest

from scenarios.run_rapp import run_rapp

HERE = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.asyncio  # async tests run under pytest-asyncio, in or out of this checkout


@pytest.mark.parametrize("robot", ["nao", "elektron"])
async def test_lamp_patrol_checks_every_lamp_and_keeps_pictures(tmp_path, robot):
    result = await run_rapp(HERE, robot, "small", 1, "check the lamps in the living", tmp_path, timeout_s=240)
    assert result["ok"], result["end"]
    final = result["reports"][-1]
    assert final["data"]["lamps"].keys() == {"l1"}  # the {room} slot chose the lamp
    assert result["outputs"] == ["l1.png"] and (tmp_path / "outputs" / "l1.png").stat().st_size > 1000
    trace = [json.loads(line) for line in (tmp_path / "trace.jsonl").read_text().splitlines()]
    assert any(r["kind"] == "blackboard" and r["key"] == "found" and r["writer"] == "check" for r in trace)
    assert any(r["kind"] == "log" and "1 lamps to check in the living" in r["message"] for r in trace)
    progress = [(r["fraction"], r["text"]) for r in trace if r["kind"] == "progress"]
    assert progress[-1][0] == 1.0 and any(t.startswith("to l1: at (") for _, t in progress)  # the walk's feedback
