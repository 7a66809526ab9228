"""Runs lamp-patrol on the simulated robots, as `rapp run rapp rapps/examples/lamp_patrol` does: in the
small house (quick), and in the full house, scored against the world's truth (slow: minutes each).
`rapp test DIR --robot R` (RAPP_ROBOT_TYPE, as the Store's build per robot type sets it) runs only R's."""
import json
import math
import os
from pathlib import Path

import pytest

from ontology.manifest import load_manifest

HERE = Path(__file__).resolve().parent.parent
# the robots the manifest declares (the Store builds it for each), or the one the build runs for now
ROBOTS = ([os.environ["RAPP_ROBOT_TYPE"]] if os.environ.get("RAPP_ROBOT_TYPE")
          else load_manifest(Path(__file__).resolve().parent.parent).robot_types)
pytestmark = pytest.mark.asyncio  # async tests run under pytest-asyncio, in or out of this checkout


async def run_rapp(*args, **kw) -> dict:
    """scenarios.run_rapp's, imported when a test runs: collecting the tests (the Store's build per robot
    type, a collecting run of `rapp test`) took 4 s of the simulator's imports."""
    from scenarios.run_rapp import run_rapp as run
    return await run(*args, **kw)


# the Elektron's run is slow-marked for the default suite's time; its hazard run in two-robots stays
@pytest.mark.parametrize("robot", [pytest.param(r, marks=pytest.mark.slow) if r == "elektron" else r for r in ROBOTS])
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
    looked = final["data"]["localization"]  # localized by the QR codes on the way and at the lamp
    assert looked["fixed"] >= 2 and looked["frames_without_code"] <= looked["frames"] // 4


@pytest.mark.slow
@pytest.mark.timeout(1800)
@pytest.mark.parametrize("robot", ROBOTS)
async def test_lamp_patrol_in_the_full_house_gets_every_lamp_right_and_stands_where_it_meant(tmp_path, robot):
    result = await run_rapp(HERE, robot, "house", 1, "patrol the lamps", tmp_path, timeout_s=1500)
    assert result["ok"], result["end"]
    truth, lamps = result["truth"], result["reports"][-1]["data"]["lamps"]
    assert lamps and all(on == truth["lamps"][lamp]["on"] for lamp, on in lamps.items())
    stands = {r["data"]["lamp"]: r["data"]["stand"] for r in result["reports"] if "stand" in r["data"]}
    assert stands.keys() == lamps.keys()
    for lamp, (x, y) in stands.items():  # the odometry alone would be tens of cm off after these walks
        nearest = min(math.hypot(px - x, py - y) for _, px, py, _ in truth["trajectory"])
        assert nearest < 0.25, (lamp, nearest)
