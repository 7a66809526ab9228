"""The hazard-detection experiment end to end: chat command -> Core downloads the RApp -> Dynamic
and Cloud Agents check the hazards -> report to the user -> destroyed; scored against ground truth."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from agents.services.context import ServiceContext, ServiceState
from agents.services.errors import ServiceError
from agents.services.home import get_info, upload_info
from agents.tracing import read_trace
from ontology.services.home import GetHomeInfo, HomeInfo, UploadHomeInfo
from scenarios.hazard import run_hazard_detection
from scenarios.home_setup import hazard_list, hazard_overrides

from .test_cli import arapp

RESULT_KEYS = {"robot", "seed", "hazards", "all_correct", "localization_error_m", "max_tracking_error_m",
               "duration_sim_s", "duration_wall_s", "trace", "plot", "finished", "end", "routes_blocked",
               "person_contacts", "object_contacts", "strategies", "replans", "obstacles_marked", "estops",
               "ok", "reason", "frames", "trigger", "house", "lived_in", "link", "daylight", "drive",
               "scheduled", "rtf", "command_sim_s", "disturbances", "during"}


def structure_events(trace: list[dict], rapp: str) -> list[str]:
    return [r["event"] for r in trace if r["kind"] == "structure" and r.get("rapp") == rapp
            and r["event"] in ("spawn", "cloud-spawn", "cloud-destroy", "destroy")]


def check_run(result: dict, out: Path, hazard_ids: set[str]) -> None:
    assert set(result) == RESULT_KEYS
    # realism is asked for, never the default
    assert result["lived_in"] is None and result["link"] is None and result["daylight"] is None
    assert result["drive"] == "statistical"
    # what a re-simulation gives again (tests/test_hazard_resim.py): when the command was given, in simulated s
    assert isinstance(result["command_sim_s"], float) and result["command_sim_s"] >= 0.0
    assert {h["id"] for h in result["hazards"]} == hazard_ids
    assert result["all_correct"], result["hazards"]
    assert result["ok"] and result["finished"], result["reason"]
    trace = read_trace(result["trace"])
    events = structure_events(trace, "hazard-detection")
    shared = [r for r in trace if r["kind"] == "message" and r["dir"] == "recv" and r["action"] == "add_pose_fix"
              and r["agent"].startswith("core-") and r["performative"] == "request"]
    assert shared, "the RApp's QR fixes reach the Core's own estimate (add_pose_fix)"
    assert events[0] == "spawn" and "cloud-spawn" in events and events[-1] == "destroy", events
    chat = (out / "chat.txt").read_text()
    assert "hazard-detection finished" in chat
    assert all(f"Hazard {h} (" in chat for h in hazard_ids)  # the user was told every hazard's report
    assert Path(result["plot"]).stat().st_size > 10_000
    stems = {p.stem for p in (out / "frames").glob("*.*")}  # PNG, or JPEG from a noisy camera
    assert {s.split("-look")[0] for s in stems} == hazard_ids <= stems  # a door looked at again: <id>-lookN too
    assert json.loads((out / "result.json").read_text()) == result
    assert check_recording(out, [result["robot"]])[result["robot"]] == result["frames"]["captured"]


RANGE_SENSOR = {"nao": "sonar", "elektron": "laser"}  # what each robot's safety check reads


def check_recording(out: Path, robots: list[str]) -> dict[str, int]:
    """run.mcap read back (issue 45 item 1): per robot its true pose, path, estimate, every frame
    robot.jsonl recorded and its range sensor's scans (the NAO's sonars, the Elektron's laser:
    foxglove.LaserScan), with Foxglove's schemas; the map, the transforms, the chat and the Cores'
    ACL messages. Returns the frames per robot."""
    from .test_recording import _channels, _robot

    channels = _channels(out / "run.mcap")
    samples = _robot(out)
    frames = {kind: sum(s["kind"] == "image" and s["robot"] == kind for s in samples) for kind in robots}
    schema = {t: c[0] for t, c in channels.items()}
    count = {t: c[3] for t, c in channels.items()}
    assert schema["/map"] == "foxglove.Grid" and count["/map"] == 1
    assert schema["/chat"] == "foxglove.Log" and schema["/events"] == "foxglove.Log"
    for kind in robots:
        expect = {"pose": "foxglove.PoseInFrame", "estimate": "foxglove.PoseInFrame", "path": "foxglove.PosesInFrame",
                  "camera": "foxglove.CompressedImage", RANGE_SENSOR[kind]: "foxglove.LaserScan"}
        for name, want in expect.items():
            assert schema.get(f"/{kind}/{name}") == want and count[f"/{kind}/{name}"] > 0, (kind, name, sorted(channels))
        assert count[f"/{kind}/camera"] == frames[kind]
        cores = [t for t in channels if t.startswith(f"/acl/core-{kind}")]
        assert cores and all(schema[t] == "rapp.AclMessage" for t in cores), sorted(channels)
    assert count["/tf"] == sum(count[f"/{kind}/pose"] for kind in robots)
    return frames


# the Elektron's small-house run is slow-marked for the suite's time: by default it runs the door
# check in test_two_robots_small_house and both robots' lamp checks in rapps/examples/lamp_patrol.
# The NAO's is started by its schedule, as `rapp run hazard-detection --scheduled` starts it (paper 000
# sec. 7's trigger), a process of its own; the chat command's path is test_two_robots_small_house's
@pytest.mark.parametrize("robot", ["nao", pytest.param("elektron", marks=pytest.mark.slow)])
async def test_hazard_detection_small_house(tmp_path, robot):
    if robot == "nao":
        res = await arapp("run", "hazard-detection", "--robot", robot, "--seed", "1", "--house", "small", "--scheduled",
                          "--out", tmp_path, "--quiet", timeout=1200)
        assert res.returncode == 0 and "(started by its schedule)" in res.stdout, (res.stdout[-2000:], res.stderr[-3000:])
        result = json.loads((tmp_path / "result.json").read_text())
        assert result["trigger"] == "scheduled"
        trace = read_trace(result["trace"])
        kept = next(r for r in trace if r.get("event") == "schedule-kept")
        due = next(r for r in trace if r.get("event") == "schedule-due")
        spawn = next(r for r in trace if r.get("event") == "spawn")
        assert kept["t"] < due["t"] < spawn["t"] and due["trigger"] == "scheduled" and due["rapp"] == "hazard-detection"
        assert "every day at 22:00" in (tmp_path / "chat.txt").read_text()
    else:
        result = await run_hazard_detection(robot, seed=1, house="small", out_dir=tmp_path)
    check_run(result, tmp_path, {"d1", "l1"})
    assert result["localization_error_m"] <= 0.05
    assert result["max_tracking_error_m"] <= 0.10
    frames = result["frames"]  # localization looks where the codes are: few frames, nearly all with a code
    assert frames["captured"] >= frames["frames"] + len(result["hazards"])  # the rest: the checks
    # about 14 frames here: one empty frame is 7 %, and a loaded machine (the suite's four workers on
    # two cores) blurred a second one once; the 10 % goal is the full house's (rapp bench --only mainjob)
    assert frames["no_code_share"] <= 0.20 and frames["frames_per_localization"] <= 3
    door = next(h for h in result["hazards"] if h["type"] == "door")
    assert abs(door["estimated_angle"] - door["true_angle"]) <= 10


def test_home_info_is_per_user(tmp_path):
    state = ServiceState(work_dir=tmp_path)
    info = HomeInfo(home_id="home", map_id="m", hazards=[])
    upload_info(UploadHomeInfo(info=info), ServiceContext("alice", state))
    assert get_info(GetHomeInfo(home_id="home"), ServiceContext("alice", state)) == info
    with pytest.raises(ServiceError, match="no home"):
        get_info(GetHomeInfo(home_id="home"), ServiceContext("bob", state))


def test_seeded_door_states_and_hazard_list():
    from robots import World

    assert hazard_overrides("house", 4) == hazard_overrides("house", 4)
    overrides = hazard_overrides("house", 4)
    assert overrides["doors"]["d_living"] >= 80  # the passage door stays open
    world = World.from_file("house", seed=4, overrides=overrides)
    try:
        kinds = [h.type for h in hazard_list(world, "house")]
    finally:
        world.close()
    assert kinds.count("door") >= 2 and kinds.count("lamp") >= 2


@pytest.mark.slow
@pytest.mark.parametrize("robot", ["nao", "elektron"])
async def test_hazard_detection_full_house(tmp_path, robot):
    result = await run_hazard_detection(robot, seed=1, house="house", out_dir=tmp_path)
    check_run(result, tmp_path, {"d_kitchen", "d_bedroom", "l_living", "l_office"})
    assert result["localization_error_m"] <= 0.05
    assert result["max_tracking_error_m"] <= 0.10


def check_two_robots(result: dict, out: Path, split: dict) -> None:
    assert set(result["robots"]) == {"nao", "elektron"}
    events = read_trace(result["trace"])
    spawns = [r for r in events if r["kind"] == "structure" and r.get("event") == "spawn"
              and r.get("rapp") == "hazard-detection"]
    assert len(spawns) == 2  # one Dynamic Agent per robot, same Store and Platform
    for kind, r in result["robots"].items():
        assert {h["id"] for h in r["hazards"]} == split[kind]
        assert r["all_correct"], (kind, r["hazards"])
        assert r["localization_error_m"] <= 0.05 and r["max_tracking_error_m"] <= 0.10, (kind, r)
        assert "hazard-detection finished" in (out / kind / "chat.txt").read_text()
    assert json.loads((out / "result.json").read_text()) == result
    check_recording(out, list(result["robots"]))


async def test_two_robots_small_house(tmp_path):
    from scenarios.two_robots import SPLIT, run_two_robots

    result = await run_two_robots(seed=1, house="small", out_dir=tmp_path)
    check_two_robots(result, tmp_path, SPLIT["small"])


@pytest.mark.slow
async def test_two_robots_full_house(tmp_path):
    from scenarios.two_robots import SPLIT, run_two_robots

    result = await run_two_robots(seed=1, house="house", out_dir=tmp_path)
    check_two_robots(result, tmp_path, SPLIT["house"])


def test_table_rows_and_markdown():
    from scenarios.hazard_table import judge, markdown, summary_rows

    def run(robot, seed, loc, trk, wrong=(), house="generated"):
        hazards = [{"id": h, "true_state": "open", "reported_state": "open" if h not in wrong else "unknown"}
                   for h in ("d1", "l1")]
        return {"robot": robot, "seed": seed, "house": house, "hazards": hazards, "all_correct": not wrong,
                "localization_error_m": loc, "max_tracking_error_m": trk, "duration_sim_s": 100.0,
                "duration_wall_s": 30.0, "finished": True, "end": "finished"}

    failed = {"robot": "elektron", "seed": 2, "house": "generated", "failed": "TimeoutError: x",
              "hazards": [{"id": "d1", "true_state": "open", "reported_state": None}]}  # counted as wrong
    results = [run("nao", 1, 0.012, 0.071), run("nao", 2, 0.062, 0.08, wrong=("l1",)),
               run("elektron", 1, None, 0.03, house="house"), failed]
    summary = summary_rows(results)
    # 3 of 4 checks right: under the 98 % bar; the NAO's 6.2 cm is inside the paper's 10 cm
    assert "nao       checks right 3/4 (75.0 %; goal >= 98 %: NOT met)" in summary
    assert "nao       runs ended by themselves 2/2 (met); failed runs 0; wall 30 s a run" in summary
    assert any("nao       localization" in line and "(paper 10.0 cm: met)" in line for line in summary)
    assert "elektron  checks right 2/3 (66.7 %; goal >= 98 %: NOT met)" in summary
    assert "elektron  runs ended by themselves 1/2 (NOT met); failed runs 1; wall 30 s a run" in summary
    assert not any(line.startswith("elektron  localization") for line in summary)  # no localization: no row
    nao = judge(results[:2], "nao")
    assert nao["loc_max_m"] == 0.062 and nao["track_met"] and not nao["checks_met"]
    assert not judge([run("elektron", 3, 0.071, 0.05)], "elektron")["loc_met"]  # the Elektron's bar is 7 cm
    text = markdown(results, "T")
    assert "| nao | generated | 2 | 6.2 | 8.0 | 1/2 |  | 100 | 30 | l1 |  |" in text
    assert "| elektron | house | 1 | n/a | 3.0 | 2/2 |  | 100 | 30 |  |  |" in text
    assert "| elektron | generated | 2 | | | 0/1 | | | | | TimeoutError: x |" in text


def test_table_seeds_are_drawn_at_run_time_and_can_be_repeated(capsys, monkeypatch):
    """Issue 42: worlds nobody tuned for: the table draws its seeds when it starts and prints the
    --seed-list that repeats them."""
    import argparse

    from scenarios import hazard_table as T

    def args(**kw):
        return argparse.Namespace(**{"houses": None, "full_house": 0, "seeds": 3, "house": "house", "seed_list": None,
                                     **kw})

    first, second = T.table_runs(args()), T.table_runs(args())
    assert len(first) == 3 and {h for h, _ in first} == {"house"} and first != second
    runs = T.table_runs(args(houses=4, full_house=1))
    assert [h for h, _ in runs] == ["generated"] * 4 + ["house"]
    assert T.table_runs(args(seed_list=["generated:417", "88"])) == [("generated", 417), ("house", 88)]
    assert T.table_runs(args(houses=2, seed_list=["5"])) == [("generated", 5)]
    with pytest.raises(ValueError, match="HOUSE"):
        T.table_runs(args(seed_list=["attic:3"]))

    async def fake_run(robot, seed, house, out_dir, timeout_s):  # the runs themselves: not this test's subject
        raise TimeoutError("no run here")

    monkeypatch.setattr(T, "run_hazard_detection", fake_run)
    import asyncio
    import tempfile
    from pathlib import Path

    rows = asyncio.run(T.run_table([("house", 88)], ["nao"], Path(tempfile.mkdtemp())))
    assert "repeat: --seed-list house:88" in capsys.readouterr().out
    assert rows[0]["failed"] and {h["id"] for h in rows[0]["hazards"]} == {"d_kitchen", "d_bedroom", "l_living",
                                                                           "l_office"}


def test_table_from_json_merges_files(tmp_path):
    from scenarios.hazard_table import main

    def run(robot, house, seed, loc):
        return {"robot": robot, "seed": seed, "house": house, "hazards": [{"id": "d1", "true_state": "open",
                "reported_state": "open"}], "all_correct": True, "localization_error_m": loc,
                "max_tracking_error_m": 0.05, "duration_sim_s": 1.0, "duration_wall_s": 1.0, "finished": True}

    (tmp_path / "a.json").write_text(json.dumps([run("nao", "generated", 1, 0.02), run("nao", "house", 1, 0.02)]))
    (tmp_path / "b.json").write_text(json.dumps([run("elektron", "generated", 1, 0.08)]))
    md = tmp_path / "t.md"
    assert main(["--from-json", str(tmp_path / "a.json"), str(tmp_path / "b.json"), "--markdown", str(md)]) == 1
    text = md.read_text()  # the Elektron's 8 cm misses its 7 cm bar: exit 1
    assert text.startswith("# Hazard detection on 1 generated house (random seeds) and the full 20 m x 20 m house")
    assert "| elektron | generated | 1 | 8.0 |" in text


@pytest.mark.slow
def test_hazard_table_two_generated_houses(tmp_path):
    """Issue #17 item 4, short version: both robots in 2 generated houses, image-only door method,
    judged against the paper's bars (checks >= 95 % right, localization and tracking per robot)."""
    from scenarios.hazard_table import judge, main

    assert main(["--houses", "2", "--out", str(tmp_path), "--markdown", str(tmp_path / "t.md")]) == 0
    results = json.loads((tmp_path / "table.json").read_text())
    assert len(results) == 4 and not any(r.get("failed") for r in results)
    for robot in ("nao", "elektron"):
        j = judge([r for r in results if r["robot"] == robot], robot)
        assert j["checks_met"] and j["loc_met"] and j["track_met"], j
