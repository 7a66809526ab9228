"""`rapp run hazard-detection --replay RUN_DIR` (issue 45 item 4): a re-simulation runs the recorded
world again, with every setting the recorded result.json names (robot, seed, house, the realism knobs:
lived-in, link, daylight, drive; disturbances, schedule, the command's simulated time), and refuses
with a clear error a recording whose settings it cannot apply. No simulation runs here: the hazard run
is replaced by one that keeps the keywords it was given (so are two-robots' recording options)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from robots.lighting import Daylight
from robots.lived_in import LivedIn
from scenarios import hazard, resim
from scenarios.hazard import FULL_LINK, OUTCOMES, REPLAYED, main, recorded_settings, time_of_day
from xmpp_server.link import LinkFaults

from .test_hazard_scenario import RESULT_KEYS


class Started(Exception):
    """The re-simulation started: its keywords are in `kw`."""

    def __init__(self, kw: dict):
        super().__init__("started")
        self.kw = kw


@pytest.fixture
def started(monkeypatch):
    async def fake_run(**kw):
        raise Started(kw)

    monkeypatch.setattr(hazard, "run_hazard_detection", fake_run)


@pytest.fixture(scope="module")
def realistic() -> dict:
    """result.json of a `--realism full --seed 7` NAO run in the small house, as run_hazard_detection
    writes it: the world's own accounts of what lived-in and daylight changed, the link's faults and
    what it did, the mechanical drive, the command's simulated time."""
    from scenarios.home_setup import scenario_world

    world = scenario_world("small", 7, lived_in=LivedIn(seed=7), daylight=Daylight(seed=7))
    try:
        lived_in, daylight = world.lived_in, world.daylight
    finally:
        world.close()
    link = {**LinkFaults.parse(FULL_LINK, seed=7).describe(), "connections": 3, "refused": 1, "reset": 1,
            "chunks": 812, "bytes": 90210, "lost": 7, "outages_done": [[60.0, 65.0]]}
    return {"robot": "nao", "seed": 7, "house": "small", "hazards": [], "all_correct": True, "ok": True,
            "finished": True, "trigger": "command", "lived_in": lived_in, "daylight": daylight, "link": link,
            "drive": "mechanical", "scheduled": None, "rtf": 0.0, "command_sim_s": 12.35, "disturbances": None,
            "during": None}


def _recording(tmp_path: Path, result: dict) -> Path:
    (tmp_path / "result.json").write_text(json.dumps(result))
    return tmp_path


def test_a_realistic_run_is_re_simulated_with_every_recorded_knob(tmp_path, realistic, started, capsys):
    with pytest.raises(Started) as run:
        main(["--replay", str(_recording(tmp_path, realistic)), "--quiet"])
    kw = run.value.kw
    assert (kw["robot"], kw["seed"], kw["house"]) == ("nao", 7, "small")
    assert kw["lived_in"] == LivedIn(seed=7)  # before: None, the house as mapped
    assert kw["daylight"] == Daylight(seed=7, hour=None)  # before: None, the studio light
    assert kw["link"] == LinkFaults.parse(FULL_LINK, seed=7)  # before: None, a perfect link
    assert kw["mechanical_drive"] is True and kw["command_at"] == 12.35
    assert "realism: lived-in, link, daylight, mechanical drive" in capsys.readouterr().out


def test_the_recorded_package_is_run_again_not_todays_source(tmp_path, realistic, started, capsys):
    """The RApp of the recorded run (packages/, what its Core downloaded), where the recording kept it."""
    import hashlib

    data = b"the recorded hazard RApp"
    sha = hashlib.sha256(data).hexdigest()
    (tmp_path / "packages").mkdir()
    (tmp_path / "packages" / f"{sha}.rapp").write_bytes(data)
    core, dyn = "core-nao1@localhost", "dyn-nao1-hazard-detection-1@localhost"
    trace = [{"t": 1.0, "kind": "structure", "pid": 1, "agent": core, "event": "download", "rapp": "hazard-detection",
              "sha256": sha},
             {"t": 2.0, "kind": "structure", "pid": 1, "agent": core, "event": "spawn", "rapp": "hazard-detection",
              "dynamic": dyn}]
    (tmp_path / "trace.jsonl").write_text("".join(json.dumps(r) + "\n" for r in trace))
    (tmp_path / "messages.jsonl").write_text("")
    with pytest.raises(Started) as run:
        main(["--replay", str(_recording(tmp_path, realistic)), "--quiet"])
    assert run.value.kw["rapp"] == tmp_path / "packages" / f"{sha}.rapp"  # before: today's rapps/hazard_detection
    assert f"the recorded package {sha}.rapp" in capsys.readouterr().out


def test_an_older_recording_without_knobs_runs_the_plain_world(tmp_path, started):
    old = {"robot": "elektron", "seed": 3, "house": "house", "hazards": [], "ok": True, "trigger": "command"}
    with pytest.raises(Started) as run:
        main(["--replay", str(_recording(tmp_path, old)), "--quiet"])
    kw = run.value.kw
    assert (kw["robot"], kw["seed"], kw["house"]) == ("elektron", 3, "house")
    assert kw["lived_in"] is kw["daylight"] is kw["link"] is kw["command_at"] is kw["rapp"] is None
    assert kw["mechanical_drive"] is False


@pytest.mark.parametrize("change, says", [
    ({"weather": {"rain": 1}}, "weather, which this build does not know"),
    ({"lived_in": {"moved": [], "knobs": {"seed": 7, "pets": 2}}}, "lived_in"),
    ({"daylight": {"hour": 9.0}}, "daylight"),
    ({"link": {"delay_s": 0.04, "teleport": True}}, "link"),
    ({"drive": "hovercraft"}, "hovercraft"),
    ({"during": "stop_and_resume"}, "rapp run disturbances"),
    ({"trigger": "scheduled", "scheduled": None}, "schedule"),
])
def test_a_recording_whose_settings_cannot_be_applied_is_refused(tmp_path, realistic, started, capsys, change, says):
    code = main(["--replay", str(_recording(tmp_path, {**realistic, **change})), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "cannot re-simulate" in err and says in err, err


def test_replay_refuses_settings_given_beside_it(tmp_path, realistic, started, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--replay", str(_recording(tmp_path, realistic)), "--seed", "8", "--lived-in"])
    assert exit_.value.code == 2
    assert "--seed, --lived-in cannot be given with it" in capsys.readouterr().err


def test_every_key_of_a_hazard_result_is_replayed_or_an_outcome():
    """A key added to the result must be classified: else a re-simulation refuses every new recording."""
    assert RESULT_KEYS <= REPLAYED | OUTCOMES, RESULT_KEYS - REPLAYED - OUTCOMES
    assert recorded_settings({"robot": "nao", "seed": 1, "house": "small"})["rtf"] == 0.0


def test_a_re_simulation_in_another_world_is_told_apart(tmp_path, realistic):
    old, new = tmp_path / "old", tmp_path / "new"
    old.mkdir(), new.mkdir()
    traj = {"truth": {"trajectory": [[0.0, 1.0, 1.0, 0.0], [1.0, 1.2, 1.0, 0.0]]}}
    _recording(old, {**realistic, **traj})
    other_link = {**realistic["link"], "connections": 5, "lost": 9}  # what the link did differs: fine
    _recording(new, {**realistic, **traj, "link": other_link})
    c = resim.compare(old, new, "nao")
    assert c.ok, c.text()
    assert "the world's lived_in, daylight, link as recorded" in c.same
    _recording(new, {**realistic, **traj, "lived_in": None, "drive": "statistical"})
    c = resim.compare(old, new, "nao")
    assert not c.ok and any(d.startswith("lived_in:") for d in c.differ) and any(d.startswith("drive:") for d in c.differ)
    _recording(old, {**realistic, **traj, "delivery": "speech"})  # said aloud then, typed now: another run
    _recording(new, {**realistic, **traj, "delivery": "chat"})
    c = resim.compare(old, new, "nao")
    assert not c.ok and any(d.startswith("delivery:") for d in c.differ), c.text()

    door = {"id": "d1", "type": "door", "true_state": "open", "reported_state": "open", "true_angle": 40.0,
            "estimated_angle": 41.0}
    _recording(old, {**realistic, **traj, "hazards": [door]})
    _recording(new, {**realistic, **traj, "hazards": [{**door, "estimated_angle": 43.0}]})
    c = resim.compare(old, new, "nao")
    assert c.ok and any("hazards drawn from the seed" in x for x in c.same), c.text()
    _recording(new, {**realistic, **traj, "hazards": [{**door, "true_angle": 55.0}]})  # another world, same report
    c = resim.compare(old, new, "nao")
    assert not c.ok and any("the world's hazards" in d for d in c.differ), c.text()


@pytest.mark.parametrize("bad", ["18:70", "18:", "18:5", "7:60", "24:00", "-1", "-0:30", "nan", "inf", "1e1", "noon"])
def test_a_time_of_day_out_of_the_clock_is_an_argument_error(bad, capsys):
    with pytest.raises(argparse.ArgumentTypeError, match="--daylight"):
        time_of_day(bad)
    with pytest.raises(SystemExit) as exit_:
        main(["--daylight", bad, "--quiet"])
    assert exit_.value.code == 2 and "--daylight" in capsys.readouterr().err


def test_a_time_of_day_on_the_clock_is_taken():
    assert time_of_day("18:30") == 18.5 and time_of_day("07:15") == 7.25 and time_of_day("0:00") == 0.0
    assert time_of_day("23:59") == pytest.approx(23 + 59 / 60) and time_of_day("18.5") == 18.5
    assert time_of_day("7") == 7.0 and time_of_day("random") is None


def test_two_robots_and_the_disturbances_can_be_run_without_a_recording(monkeypatch):
    """`rapp run two-robots|disturbances --no-record` / `--no-frames`, as every other scenario that
    records (docs/recordings.md); the options did not exist."""
    from scenarios import disturbance_suite, two_robots

    async def fake_run(*args, **kw):
        raise Started(kw)

    monkeypatch.setattr(two_robots, "run_two_robots", fake_run)
    with pytest.raises(Started) as run:
        two_robots.main(["--no-record"])
    assert run.value.kw["record"] is False and run.value.kw["frames"] is True
    with pytest.raises(Started) as run:
        two_robots.main(["--no-frames"])
    assert run.value.kw["record"] is True and run.value.kw["frames"] is False
    monkeypatch.setattr(disturbance_suite, "run_case", fake_run)
    with pytest.raises(Started) as run:
        disturbance_suite.main(["--no-record", "--case", "door-closed", "--robot", "nao"])
    assert run.value.kw["record"] is False and run.value.kw["frames"] is True
