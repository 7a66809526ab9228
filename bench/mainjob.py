"""The main job against its floor (issue 46): the README's hazard run (`rapp run hazard-detection --robot R
--seed 1`, the full house), on a NAO and an Elektron, each measured in the same run as its floor.

    python -m bench.mainjob [--robots nao elektron] [--house house] [--seed 1] [--json FILE]

- job: the README's command as a user runs it (a fresh process tree: XMPP server, Store, Platform, the
  Core with its World and render processes, the RApp's Dynamic and Cloud Agents), wall time from start
  to exit; its result.json gives the localization's accuracy and its frames.
- floor: what the job cannot avoid, in bare PyBullet: the same renders (number and resolution, each from
  the robot's recorded pose at its capture time, head ahead: the head's angles are not recorded) with
  getCameraImage (TinyRenderer, the same light) in one process of its own on the same house, and
  the same number of simulation steps (the World's are kinematic: the robot's base set, once a step). Nothing else: no camera model, no encoding, no
  messages, no QR decoding, no planning.
- floor_banded: the same renders in two horizontal bands on two processes at once, as the job renders
  its 1280x960 frames (robots/render_process.py): what the floor would be with the job's use of two cores.

Metrics per robot: mainjob_<robot> (job wall s, ratio to the floor), mainjob_<robot>_no_code (share of the
localization's frames without a code, %), mainjob_<robot>_localization (error of the last fix, cm).
`tiny` (the suite's plumbing test): the small house, one robot, a floor of a few frames.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from ontology import robot_types
from robots.simclock import STEP_S
from scenarios.recording import ROBOT_LOG

from .common import ROOT, end_group, log, metric, spawn

README_HOUSE = "house"
README_SEED = 1


def run_job(robot: str, out: Path, house: str = README_HOUSE, seed: int = README_SEED, timeout: float = 1800.0
            ) -> dict:
    """The README's hazard run as a user runs it; its result, wall time and the renders it made."""
    cmd = [sys.executable, "-m", "cli.main", "run", "hazard-detection", "--robot", robot, "--seed", str(seed),
           "--house", house, "--out", str(out), "--quiet"]
    t0 = time.perf_counter()
    proc = spawn(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _, stderr = proc.communicate(timeout=timeout)
        wall = time.perf_counter() - t0
    finally:
        end_group(proc)  # what the run left behind, or all of it when the bench is interrupted
    try:
        result = json.loads((out / "result.json").read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise RuntimeError(f"hazard run of {robot} wrote no result (exit {proc.returncode}): {stderr[-400:]}") from e
    images, poses = recorded_renders(out / ROBOT_LOG, robot)
    return {"wall_s": wall, "result": result, "images": images, "poses": poses, "exit": proc.returncode}


def recorded_renders(path: Path, robot: str) -> tuple[list[tuple[int, int, float]], list[tuple[float, list[float]]]]:
    """(width, height, sim time) of every frame the robot captured, and its (sim time, pose) samples,
    from the run's recording."""
    images, poses = [], []
    with path.open() as f:
        for line in f:
            if '"kind":"image"' not in line and '"kind":"pose"' not in line:
                continue
            rec = json.loads(line)
            if rec.get("robot") != robot:
                continue
            if rec["kind"] == "image":
                images.append((int(rec["width"]), int(rec["height"]), float(rec["sim"])))
            else:
                poses.append((float(rec["sim"]), list(rec["pose"])))
    return images, poses


def pose_at(poses: list[tuple[float, list[float]]], t: float) -> list[float]:
    best = poses[0][1]
    for s, pose in poses:
        if s > t:
            break
        best = pose
    return best


# ---- the floor (runs in a process of its own: bare PyBullet, nothing of the job loaded around it)
def floor_main(spec_path: str) -> None:
    """Child: render the spec's frames and step the spec's steps in bare PyBullet; print JSON timings."""
    import numpy as np
    import pybullet as p

    from robots.render_process import SPLIT_MIN_PIXELS, RenderJob, _mirror_scene_class, band_projection
    from robots.receptors import LIGHT, camera_matrices
    from robots.bodies import ROBOT_SPECS
    from robots.floorplan import load_plan
    from robots.world import HOUSES
    from scenarios.home_setup import hazard_overrides

    spec = json.loads(Path(spec_path).read_text())
    plan = load_plan(HOUSES / f"{spec['house']}.yaml", seed=spec["seed"], overrides=hazard_overrides(spec["house"], spec["seed"]))
    scene = _mirror_scene_class()(plan)  # the house's bodies, built by the same code as the World's
    kind = spec["robot"]
    rspec = ROBOT_SPECS[kind]
    cam = rspec.cameras[0]
    frames = spec["frames"]
    scene.apply(RenderJob(0, 0, [], [], None, add=[("r", kind, tuple(frames[0][2]) if frames else (0, 0, 0))]))
    uid = scene.bodies["r"][0]
    cid = scene.cid
    link = next(i for i in range(p.getNumJoints(uid, physicsClientId=cid))
                if p.getJointInfo(uid, i, physicsClientId=cid)[12].decode() == cam.link)

    def matrices(pose, w, h):
        scene.apply(RenderJob(w, h, [], [], None, poses={"r": tuple(pose)}))
        st = p.getLinkState(uid, link, computeForwardKinematics=True, physicsClientId=cid)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = np.array(p.getMatrixFromQuaternion(st[5])).reshape(3, 3), st[4]
        return camera_matrices(T, cam, w, h, cid)

    flags = p.ER_NO_SEGMENTATION_MASK if not scene.emissive else 0
    jobs = [(w, h, matrices(pose, w, h)) for w, h, pose in frames]
    band = spec.get("band")  # (k, n): that band of every frame the job renders in bands, the rest in band 0
    t0 = time.perf_counter()
    for w, h, (view, proj) in jobs:
        if band is not None and w * h >= SPLIT_MIN_PIXELS:
            proj, h = band_projection(proj, band[0], band[1]), h // band[1]
        elif band is not None and band[0]:
            continue
        p.getCameraImage(w, h, view, proj, renderer=p.ER_TINY_RENDERER, flags=flags, physicsClientId=cid, **LIGHT)
    render_s = time.perf_counter() - t0
    # a step of the World is kinematic (robots/world.py: the controllers set poses; no stepSimulation):
    # its bare floor, the robot's base set along its recorded poses
    track = [(pose[0], pose[1], p.getQuaternionFromEuler((0, 0, pose[2]))) for _, _, pose in frames] or [(0, 0, (0, 0, 0, 1))]
    t0 = time.perf_counter()
    for i in range(int(spec["steps"])):
        x, y, q = track[i % len(track)]
        p.resetBasePositionAndOrientation(uid, (x, y, 0.0), q, physicsClientId=cid)
    step_s = time.perf_counter() - t0
    print(json.dumps({"render_s": render_s, "step_s": step_s, "frames": len(jobs)}))


def _floor_process(spec: dict, workdir: Path, tag: str) -> subprocess.Popen:
    path = workdir / f"floor-{tag}.json"
    path.write_text(json.dumps(spec))
    return spawn([sys.executable, "-m", "bench.mainjob", "--floor", str(path)], cwd=ROOT,
                 stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)


def _answer(proc: subprocess.Popen) -> dict:
    try:
        out, _ = proc.communicate(timeout=1800)
    finally:
        end_group(proc)
    if proc.returncode:
        raise RuntimeError(f"floor process exited {proc.returncode}")
    return json.loads(out.strip().splitlines()[-1])


def measure_floor(robot: str, house: str, seed: int, job: dict, workdir: Path, max_frames: int | None = None
                  ) -> dict:
    """The floor of one job: its renders and steps in bare PyBullet, serial and in two bands at once."""
    frames = [(w, h, pose_at(job["poses"], t)) for w, h, t in job["images"]][:max_frames]
    result = job["result"]
    steps = int(round(result["duration_sim_s"] / STEP_S))  # the World's default step
    base = {"robot": robot, "house": house, "seed": seed, "frames": frames}
    serial = _answer(_floor_process({**base, "steps": steps}, workdir, "serial"))
    banded = [_floor_process({**base, "steps": 0, "band": (k, 2)}, workdir, f"band{k}") for k in range(2)]
    bands = [_answer(b) for b in banded]
    return {"render_s": serial["render_s"], "step_s": serial["step_s"], "steps": steps,
            "banded_render_s": max(b["render_s"] for b in bands), "frames": len(frames)}


def measure(robots: list[str], house: str = README_HOUSE, seed: int = README_SEED, max_floor_frames: int | None = None
            ) -> list[dict]:
    out = []
    with tempfile.TemporaryDirectory(prefix="bench-mainjob-") as tmp:
        workdir = Path(tmp)
        for robot in robots:
            log(f"mainjob {robot}: the README's hazard run ({house}, seed {seed})")
            job = run_job(robot, workdir / robot, house, seed)
            log(f"mainjob {robot}: {job['wall_s']:.1f} s wall; the floor of its {len(job['images'])} frames")
            floor = measure_floor(robot, house, seed, job, workdir, max_floor_frames)
            out += metrics(robot, job, floor)
    return out


def metrics(robot: str, job: dict, floor: dict) -> list[dict]:
    r = job["result"]
    fr = r.get("frames") or {}
    floor_s = floor["render_s"] + floor["step_s"]
    banded_s = floor["banded_render_s"] + floor["step_s"]
    sizes = Counter(f"{w}x{h}" for w, h, _ in job["images"])
    loc_cm = None if r.get("localization_error_m") is None else 100 * r["localization_error_m"]
    common = dict(robot=robot, all_correct=r.get("all_correct"), ok=r.get("ok"))
    return [
        metric(f"mainjob_{robot}", job["wall_s"], "s", floor_s, job["wall_s"] / floor_s, len(job["images"]),
               floor_banded_s=banded_s, ratio_banded=job["wall_s"] / banded_s, floor_render_s=floor["render_s"],
               floor_step_s=floor["step_s"], steps=floor["steps"], floor_frames=floor["frames"],
               renders=dict(sizes), sim_s=r.get("duration_sim_s"), **common),
        metric(f"mainjob_{robot}_no_code", 100 * (fr.get("no_code_share") or 0.0), "%", None, None,
               int(fr.get("frames") or 0), frames_per_localization=fr.get("frames_per_localization"),
               localizations=fr.get("localizations")),
        metric(f"mainjob_{robot}_localization", loc_cm, "cm", None, None, int(fr.get("localizations") or 0),
               tracking_cm=None if r.get("max_tracking_error_m") is None else 100 * r["max_tracking_error_m"],
               **common),
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.mainjob", description=__doc__.splitlines()[0])
    ap.add_argument("--robots", nargs="+", default=list(robot_types.names()), choices=robot_types.names())
    ap.add_argument("--house", default=README_HOUSE)
    ap.add_argument("--seed", type=int, default=README_SEED)
    ap.add_argument("--json", metavar="FILE")
    ap.add_argument("--floor", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.floor:
        floor_main(a.floor)
        return 0
    from .common import table

    res = measure(a.robots, a.house, a.seed)
    print(table(res))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
