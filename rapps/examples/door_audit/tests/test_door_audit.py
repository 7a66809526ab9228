"""Runs door-audit in the full house on both robots, as `rapp run rapp rapps/examples/door_audit`
does, and scores its per-door list against the world's truth (result.json's `truth`). Each robot
audits the doors of the room it starts in (the whole house takes minutes), at a seed drawn now
(DOOR_AUDIT_SEED=N repeats one); `rapp test DIR --robot R` (RAPP_ROBOT_TYPE, as the Store's build sets it) runs
only that robot's. The start room and its doors are read from the house file, as the run's world
places the robot and as the home description lists the doors: a changed house changes them here too."""
import os
import random
from pathlib import Path

import pytest
import yaml

from ontology.manifest import load_manifest

# the simulator's modules are imported in the tests: collecting them (the Store's build per robot type,
# a collecting run of `rapp test`) took 4 s of imports
HERE = Path(__file__).resolve().parent.parent
HOUSE = "house"
# the robots the manifest declares (the Store builds it for each), or the one the build runs for now
ROBOTS = [os.environ["RAPP_ROBOT_TYPE"]] if os.environ.get("RAPP_ROBOT_TYPE") else load_manifest(HERE).robot_types


def house_file() -> Path:
    from robots import HOUSES
    return HOUSES / f"{HOUSE}.yaml"


def start_room(robot: str, seed: int, house: Path | dict | None = None) -> tuple[str | None, set[str]]:
    """The room `robot` starts in at `seed` (the house file's start spec, drawn as the run's world
    draws it) and the doors the home description lists for that room with check poses (the RApp's
    list for `audit the doors of the ROOM`)."""
    from robots import ROBOT_SPECS
    from robots.floorplan import load_plan
    from scenarios.home_setup import doorway, hazard_overrides

    plan = load_plan(house or house_file(), seed, hazard_overrides(HOUSE, seed))
    x, y, _ = plan.start_pose(robot, robot, ROBOT_SPECS[robot].radius)
    room = plan.room_at(x, y)
    return room, {d.id for d in plan.doors if (way := doorway(plan, d)).checks and room in way.rooms}


def _starting_in(desc: dict, robot: str, room: str) -> dict:
    return {**desc, "robots": {**desc["robots"], robot: {"room": room}}}


@pytest.mark.parametrize("robot", ROBOTS)
def test_the_start_room_follows_the_house_file(robot):
    desc = yaml.safe_load(house_file().read_text())
    room, doors = start_room(robot, 1)
    assert doors and room == desc["robots"][robot].get("room", room)
    moved = {r["name"]: start_room(robot, 1, _starting_in(desc, robot, r["name"])) for r in desc["rooms"]}
    assert all(got == name for name, (got, _) in moved.items())
    assert any(room_doors and room_doors != doors for _, room_doors in moved.values())


# both robots in the default suite: issue 43's closing test (a RApp written from the docs, scored
# against the truth, in the full house)
@pytest.mark.asyncio  # under pytest-asyncio, in or out of this checkout
@pytest.mark.parametrize("robot", ROBOTS)
async def test_door_audit_reports_each_door_of_the_room_right(tmp_path, robot):
    from scenarios.run_rapp import run_rapp

    seed = int(os.environ.get("DOOR_AUDIT_SEED") or random.randrange(1, 10_000))
    room, expected = start_room(robot, seed)
    assert room, f"{robot} starts outside every room at seed {seed}"
    result = await run_rapp(HERE, robot, HOUSE, seed, f"audit the doors of the {room}", tmp_path, timeout_s=280)
    assert result["ok"], (seed, result["end"])
    doors, truth = result["reports"][-1]["data"]["doors"], result["truth"]["doors"]
    assert set(doors) == expected, (seed, room, doors)
    for door, row in doors.items():
        assert row["open"] == truth[door]["open"], (seed, door, row, truth[door])
