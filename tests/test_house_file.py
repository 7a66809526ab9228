"""House files (docs/houses.md): the pydantic model and its JSON Schema in step, every shipped and
generated house valid, the checks beyond the types, `rapp house new` / `check` as a user runs them,
and what the home description tells a RApp about doors (check poses from each side) and landmarks."""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest
import yaml

from cli.main import main
from robots import HOUSES
from robots.floorplan import load_plan
from robots.house_file import HouseFile, check, schema, template
from robots.house_gen import generate
from scenarios.home_setup import doorway, landmark_specs

ROOT = Path(__file__).resolve().parent.parent
SCHEMA = ROOT / "docs" / "house.schema.json"


def house_files():
    return [p for p in sorted(HOUSES.glob("*.yaml")) if "walls" in yaml.safe_load(p.read_text())]


def test_schema_file_is_what_the_model_writes():
    assert json.loads(SCHEMA.read_text()) == schema(), "run: python -m robots.house_file > docs/house.schema.json"


def test_docs_name_every_key_of_the_model():
    doc = (ROOT / "docs" / "houses.md").read_text()
    for field in HouseFile.model_fields:
        assert f"`{field}`" in doc, field
    for model in ("Door", "Lamp", "Landmark", "Furniture", "Hazards", "RobotStart"):
        for field, info in schema()["$defs"][model]["properties"].items():
            assert re.search(rf"\b{field}\b", doc), f"docs/houses.md does not mention {model}.{field}"


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_shipped_and_generated_house_is_valid(seed):
    files = house_files()
    assert {p.stem for p in files} >= {"small", "house", "twodoors"}
    for desc in [yaml.safe_load(p.read_text()) for p in files] + [generate(seed)]:
        assert check(desc)[1] == [], desc["name"]


def test_problems_beyond_the_types_are_named():
    desc = yaml.safe_load(template("flat"))
    desc["doors"].append({"id": "d1", "hinge": [1.0, 1.0], "closed_yaw": 0})  # twice, and in no wall
    desc["landmarks"].append({"id": "qr_x", "text": "QR-1", "x": 2.0, "y": 2.0})  # text twice, on no wall
    desc["hazards"]["doors"]["d9"] = "front"
    desc["robots"]["nao"] = {"room": "attic"}
    problems = "\n".join(check(desc)[1])
    for expected in ("door 'd1' is given twice", "door 'd1': its gap", "landmark text 'QR-1' is given twice",
                     "landmark 'qr_x' at (2, 2) does not hang on a wall", "unknown door 'd9'", "unknown room 'attic'"):
        assert expected in problems
    with pytest.raises(ValueError, match=r"doors.0.opens: Input should be 'left' or 'right'; lamps.0.color"):
        check({**desc, "doors": [{**desc["doors"][0], "opens": "out"}], "lamps": [{"id": "l", "x": 0, "y": 0, "color": 1}]})


def test_a_lamps_on_key_is_read_although_yaml_makes_it_true():
    desc = yaml.safe_load(template("flat").replace("on: random", "on: true"))
    assert True in desc["lamps"][0]  # PyYAML reads the key `on` as True
    assert all(load_plan(desc, seed=s).lamps[0].on for s in range(8))
    assert check(desc)[0].lamps[0].on is True


def test_every_doorway_has_a_check_pose_on_each_side_outside_the_leafs_sweep():
    plan = load_plan(HOUSES / "house.yaml", seed=1)
    for door in plan.doors:
        spec = doorway(plan, door)
        front, swing = spec.check_from("front"), spec.check_from("swing")
        assert spec.door.opens in ("left", "right")
        assert {front.room, swing.room} == set(spec.rooms), door.id  # one pose in each room it joins
        normal = (-math.sin(door.closed_yaw) * door.sign, math.cos(door.closed_yaw) * door.sign)  # the swing side
        for c, sign in ((front, -1), (swing, 1)):
            side = (c.stand.x - door.hinge[0]) * normal[0] + (c.stand.y - door.hinge[1]) * normal[1]
            assert sign * side > 0.5, (door.id, c.side)
            assert math.hypot(c.stand.x - door.hinge[0], c.stand.y - door.hinge[1]) > door.width
            assert c.clearance_m > 0.3
            heading = math.atan2(c.look_at[1] - c.stand.y, c.look_at[0] - c.stand.x)
            assert abs(math.remainder(heading - c.stand.theta, 2 * math.pi)) < 1e-6


def test_landmarks_carry_their_own_size():
    specs = landmark_specs(load_plan(HOUSES / "house.yaml", seed=1))
    assert {s.size_m for s in specs.values()} == {0.25, 0.35}
    assert specs["QR-KITCHEN-E"].size_m == 0.25 and specs["QR-HALL-S1"].size_m == 0.35
    assert specs["QR-HALL-S1"].room == "hall"


def test_rapp_house_new_then_check_draws_a_valid_house(tmp_path, capsys):
    assert main(["house", "new", "flat", "-o", str(tmp_path)]) == 0
    path = tmp_path / "flat.yaml"
    assert main(["house", "new", "flat", "-o", str(tmp_path)]) == 1  # never overwritten
    assert "exists: not overwritten" in capsys.readouterr().err
    png = tmp_path / "flat.png"
    assert main(["house", "check", str(path), "-o", str(png), "--seed", "2"]) == 0
    out = capsys.readouterr().out
    assert "flat: 6.1 m x 4.1 m, 2 rooms, 1 door, 1 lamp" in out and "(2 of 0.25 m, 1 of 0.35 m)" in out
    assert f"valid; drawn at seed 2 in {png}" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_rapp_house_check_names_each_problem_and_fails(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(template("bad").replace("hinge: [3.5, 1.0]", "hinge: [2.0, 1.0]"))
    assert main(["house", "check", str(bad), "-o", str(tmp_path / "bad.png")]) == 1
    out = capsys.readouterr().out
    assert "problem: door 'd1': its gap" in out and re.search(r"bad.yaml: \d+ problems?; drawn", out)
    bad.write_text("walls: [[0, 0, 1]]\n")
    assert main(["house", "check", str(bad)]) == 1
    assert "walls.0: List should have at least 4 items" in capsys.readouterr().err
    assert main(["house", "check", str(HOUSES / "small-disturbances.yaml")]) == 1
    assert "is a disturbance file, not a house file" in capsys.readouterr().err


def test_a_house_that_is_neither_a_file_nor_a_name_says_which_names_there_are():
    from robots import World

    with pytest.raises(FileNotFoundError) as e:  # it was "[Errno 2] No such file or directory: 'hous'"
        World.from_file("hous")
    assert str(e.value) == "no house 'hous': a house file (YAML) or one of generated, house, small, twodoors"
