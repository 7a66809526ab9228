"""House description: grid-map export, landmark map, seeded reproducibility, the full house."""
import json
import math

import cv2
import pytest
from pathlib import Path

import yaml

from robots.gridmap import FREE, OCCUPIED, UNKNOWN


def cell(img, meta, x, y):
    res, (ox, oy, _) = meta["resolution"], meta["origin"]
    col = int((x - ox) / res)
    row = img.shape[0] - 1 - int((y - oy) / res)
    return int(img[row, col])


def test_grid_map_marks_walls_furniture_occupied_and_rooms_free(make_world, tmp_path):
    w = make_world("small", seed=1, overrides={"doors": {"d1": 0}})
    png, yml = w.export_grid_map(tmp_path, name="small", resolution=0.05)
    meta = yaml.safe_load(yml.read_text())
    assert meta["image"] == "small.png" and meta["resolution"] == 0.05 and meta["negate"] == 0
    assert {"origin", "occupied_thresh", "free_thresh"} <= set(meta)
    img = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    for x, y in [(0.0, 2.0), (6.0, 1.0), (3.0, 4.0), (3.5, 3.0), (1.0, 1.0), (5.6, 3.5), (0.4, 3.6)]:
        assert cell(img, meta, x, y) == OCCUPIED, (x, y)  # outer/inner walls, table, wardrobe, lamp
    for x, y in [(2.0, 2.0), (2.0, 0.5), (4.5, 2.0), (3.5, 1.45)]:
        assert cell(img, meta, x, y) == FREE, (x, y)  # rooms and the door gap (doors excluded by default)
    assert cell(img, meta, -0.3, -0.3) == UNKNOWN
    with_doors = w.grid_map(0.05, include_doors=True)
    assert with_doors.value_at(3.5, 1.45) == OCCUPIED  # the closed door leaf fills the gap


def test_landmark_map_file(make_world, tmp_path):
    w = make_world("small", seed=1)
    path = w.write_landmark_map(tmp_path / "landmarks.yaml")
    data = yaml.safe_load(path.read_text())
    ids = {m["id"]: m for m in data["landmarks"]}
    house = yaml.safe_load((Path(__file__).resolve().parents[2] / "robots/houses/small.yaml").read_text())
    declared = {lm["id"] for lm in house["landmarks"]}
    assert set(ids) == declared and {"qr_s1", "qr_s2", "qr_s3"} <= declared  # every panel, no more
    m = ids["qr_s1"]
    assert (m["text"], m["x"], m["y"], m["z"], m["size"]) == ("QR-S1", 1.8, 3.95, 0.7, 0.25)
    assert m["yaw"] == pytest.approx(-math.pi / 2) and len(m["corners"]) == 4
    jpath = w.write_landmark_map(tmp_path / "landmarks.json")
    assert json.loads(jpath.read_text())["landmarks"][0]["id"] == "qr_s1"


def test_seeded_randomness_is_reproducible(make_world):
    a, b = make_world("house", seed=7), make_world("house", seed=7)
    assert a.ground_truth().doors == b.ground_truth().doors
    assert a.ground_truth().lamps == b.ground_truth().lamps
    assert a.add_robot("nao").pose == b.add_robot("nao").pose
    others = [make_world("house", seed=s).ground_truth().doors for s in (8, 9)]
    assert any(o != a.ground_truth().doors for o in others)


def test_overrides_fix_doors_and_lamps(make_world):
    w = make_world("house", seed=7, overrides={"doors": {"d_living": 30}, "lamps": {"l_office": True}})
    gt = w.ground_truth()
    assert gt.doors["d_living"] == 30 and gt.lamps["l_office"] is True


def test_full_house_has_required_content(make_world, tmp_path):
    w = make_world("house", seed=3)
    x0, y0, x1, y1 = w.plan.bounds
    assert x1 - x0 >= 19.9 and y1 - y0 >= 19.9
    assert len(w.plan.doors) >= 2 and len(w.plan.lamps) >= 2 and len(w.plan.furniture) >= 5
    assert len(w.landmarks) >= 6
    n, e = w.add_robot("nao"), w.add_robot("elektron")
    for r in (n, e):
        assert w.plan.clearance(r.pose[0], r.pose[1]) > r.spec.radius
    png, _ = w.export_grid_map(tmp_path)
    assert cv2.imread(str(png)).shape[0] > 400
