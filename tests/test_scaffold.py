"""`rapp new` makes a RApp that builds, runs on the simulated robot (`rapp run rapp`) and whose
own generated test passes, unchanged."""
from __future__ import annotations

import asyncio
import json
import subprocess
from pathlib import Path

from ontology.package import read_package

from .test_cli import RAPP, arapp, rapp


async def test_new_rapp_builds_runs_and_its_test_passes(tmp_path):
    dest = tmp_path / "lamp-check"
    res = rapp("new", "lamp-check", dest, "--cloud")
    assert res.returncode == 0 and "rapp run rapp" in res.stdout, res.stderr
    pkg = tmp_path / "lamp.rapp"
    assert rapp("package", "build", dest, "-o", pkg).returncode == 0
    package = read_package(pkg.read_bytes())
    assert package.manifest.name == "lamp-check" and package.manifest.cloud_entry_point
    assert "tests/test_lamp_check.py" in package.paths  # its tests are shipped: the Store builds it by them

    res = await arapp("run", "rapp", dest, "--robot", "nao", "--out", tmp_path / "out", timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "pybullet build time" not in res.stdout + res.stderr  # no third-party banner
    assert f"result {tmp_path / 'out' / 'result.json'}" in res.stdout  # the closing summary names its files
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["ok"] and result["reports"][0]["data"] == {"doubled": 42}
    # the same outputs as the hazard run: a plot of the run and the frames the RApp captured
    assert Path(result["plot"]).read_bytes()[:4] == b"\x89PNG"
    [frame] = result["frames"]
    magic = {".png": b"\x89PNG", ".jpg": b"\xff\xd8\xff"}[Path(frame).suffix]  # JPEG: a noisy camera's frame
    assert Path(frame).read_bytes()[:len(magic)] == magic
    assert "saw 320x240" in result["reports"][0]["text"]

    # the run is a recording: saved into the RApp's tests, its scaffolded replay test runs it (issue 45.3)
    saved = rapp("replay", tmp_path / "out", "--save", dest / "tests" / "recording")
    assert saved.returncode == 0 and "messages.jsonl" in saved.stdout, saved.stderr
    assert not (dest / "tests" / "recording" / "system").exists()  # no credentials copied
    # its tests as the README says, from outside the checkout, with what `pip install -e .` brings
    res = await asyncio.to_thread(subprocess.run, [*RAPP, "test", str(dest), "-q"], cwd=tmp_path, capture_output=True,
                                  text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert res.returncode == 0 and "2 passed" in res.stdout, res.stdout[-2000:] + res.stderr[-2000:]
    assert "warning" not in res.stdout.lower(), res.stdout[-2000:]  # no pytest warnings
    assert not (dest / ".pytest_cache").exists()  # nothing cached into the RApp's folder


def test_new_refuses_a_bad_name_or_a_used_directory(tmp_path):
    assert "lower-case" in rapp("new", "Bad_Name", tmp_path / "x").stderr
    (tmp_path / "used").mkdir()
    (tmp_path / "used" / "file").write_text("x")
    res = rapp("new", "ok-name", tmp_path / "used")
    assert res.returncode == 1 and "not empty" in res.stderr
