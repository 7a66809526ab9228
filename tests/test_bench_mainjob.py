"""bench/mainjob.py: the README's hazard run against its floor. The default test checks the plumbing
(the frames read from a recording, the floor's bare renders of them, the metrics and their goals) on a
made-up recording; the tiny bench (a whole hazard run) is slow-marked: `rapp bench --only mainjob` runs it."""
from __future__ import annotations

import json

import pytest

from bench import mainjob, runner


def _recording(path, robot="nao"):
    recs = [{"kind": "map", "robot": ""}, {"kind": "pose", "robot": robot, "sim": 0.0, "pose": [0.5, 0.0, 1.57]},
            {"kind": "image", "robot": robot, "sim": 1.0, "width": 1280, "height": 960},
            {"kind": "pose", "robot": robot, "sim": 2.0, "pose": [0.6, 0.4, 1.57]},
            {"kind": "pose", "robot": "other", "sim": 2.5, "pose": [9.0, 9.0, 0.0]},
            {"kind": "image", "robot": robot, "sim": 3.0, "width": 640, "height": 480}]
    path.write_text("".join(json.dumps(r, separators=(",", ":")) + "\n" for r in recs))


def test_the_floor_renders_the_recorded_frames_in_bare_pybullet(tmp_path):
    _recording(tmp_path / "robot.jsonl")
    images, poses = mainjob.recorded_renders(tmp_path / "robot.jsonl", "nao")
    assert images == [(1280, 960, 1.0), (640, 480, 3.0)] and len(poses) == 2
    assert mainjob.pose_at(poses, 1.0) == [0.5, 0.0, 1.57] and mainjob.pose_at(poses, 3.0) == [0.6, 0.4, 1.57]
    result = {"duration_sim_s": 10.0, "localization_error_m": 0.03, "max_tracking_error_m": 0.1, "all_correct": True,
              "ok": True, "frames": {"frames": 20, "localizations": 10, "no_code_share": 0.05,
                                     "frames_per_localization": 2.0}}
    job = {"images": images, "poses": poses, "result": result, "wall_s": 5.0}
    floor = mainjob.measure_floor("nao", "small", 1, job, tmp_path)
    assert floor["frames"] == 2 and floor["steps"] == 600
    assert floor["render_s"] > 0 and floor["banded_render_s"] > 0 and floor["step_s"] >= 0
    rows = {m["name"]: m for m in mainjob.metrics("nao", job, floor)}
    run = rows["mainjob_nao"]
    assert run["value"] == 5.0 and run["ratio"] == pytest.approx(5.0 / run["floor"], rel=1e-3)
    assert run["renders"] == {"1280x960": 1, "640x480": 1}
    assert rows["mainjob_nao_no_code"]["value"] == 5.0 and rows["mainjob_nao_localization"]["value"] == 3.0
    lines = runner.goal_lines(list(rows.values()))
    assert "goal mainjob_nao_no_code: <= 10 %: met" in lines
    assert runner.select(["mainjob_nao"]) == ["mainjob"]


@pytest.mark.slow  # a whole hazard run in the small house (~40 s): `rapp bench --only mainjob` runs it
def test_mainjob_tiny(tmp_path):
    out = tmp_path / "bench.json"
    code = runner.main(["--tiny", "--json", str(out), "--only", "mainjob"])
    metrics = json.loads(out.read_text())["metrics"]
    assert code == 0, [m.get("error") for m in metrics]
    run = next(m for m in metrics if m["name"] == "mainjob_nao")
    assert run["value"] > 0 and run["floor"] > 0 and run["floor_frames"] == min(3, run["n"])
