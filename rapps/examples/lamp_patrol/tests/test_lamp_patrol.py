"""Runs lamp-patrol on the simulated robots, as `rapp run rapp rapps/examples/lamp_patrol` does."""
import json
from pathlib import Path

import pytest

from scenarios.run_rapp import run_rapp

HERE = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("robot", ["nao", "elektron"])
async def test_lamp_patrol_checks_every_lamp_and_keeps_pictures(tmp_path, robot):
    result = await run_rapp(HERE, robot, "small", 1, "check the lamps in the l1", tmp_path, timeout_s=240)
    assert result["ok"], result["end"]
    final = result["reports"][-1]
    assert final["data"]["lamps"].keys() == {"l1"}  # the {room} slot chose the lamp
    assert result["outputs"] == ["l1.png"] and (tmp_path / "outputs" / "l1.png").stat().st_size > 1000
    trace = [json.loads(line) for line in (tmp_path / "trace.jsonl").read_text().splitlines()]
    assert any(r["kind"] == "blackboard" and r["key"] == "found" and r["writer"] == "check" for r in trace)
    assert any(r["kind"] == "log" and "1 lamps to check in the l1" in r["message"] for r in trace)
    assert [r["fraction"] for r in trace if r["kind"] == "progress"][-1] == 1.0
