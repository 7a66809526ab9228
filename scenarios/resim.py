"""Re-simulation (`rapp run rapp|hazard-detection ... --replay RUN_DIR`, docs/recordings.md): the
whole system run again from a recorded run's seed, house, robot and owner's command (given at the
simulated time it was given), then compared with the recording.

What is compared, and how strictly:
- the world drawn from the seed (door angles, lamps): equal, bit for bit;
- how the task ended (ok, stage, state) and the reports: the same number, the same texts once their
  numbers are set aside, the same data keys and non-numeric values; numbers within NUMBER_TOL
  (relative) or, for hazard runs, each hazard's reported state equal and its door angle within ANGLE_TOL_DEG;
- the true trajectory, as a path: every sampled point within `tolerance_m` (default TRAJECTORY_TOL_M)
  of the other run's path, and the end poses as close (when the robot moved, in simulated time, is not
  compared: it depends on when the messages arrived).
Why not bit for bit: the simulation steps in its own thread as fast as it can (rtf 0) while the agents'
messages travel between processes, so when a motion command lands, in simulated time, depends on
thread and process timing; the camera renders then see a slightly different pose and the
estimates built on them differ in their last digits. The seed's world is the same every time.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from xmpp_server.link import LinkFaults

from .recorder import distance_to_polyline
from .recording import ROBOT_LOG

TRAJECTORY_TOL_M = 0.25
NUMBER_TOL = 0.05  # relative, of a number in a report (at least 0.05 absolute)
ANGLE_TOL_DEG = 5.0
LINK_FAULTS = {f.name for f in fields(LinkFaults)}
_NUMBER = re.compile(r"-?\d+(?:\.\d+)?")


class ResimError(ValueError):
    pass


def recorded_result(run_dir: str | Path) -> dict:
    path = Path(run_dir) / "result.json"
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ResimError(f"{run_dir} holds no readable result.json ({e}): not a `rapp run` folder") from None


def trajectory(run_dir: str | Path, robot: str) -> list[tuple[float, float, float]]:
    """(sim, x, y) of the robot's true pose: robot.jsonl, else result.json's truth."""
    d = Path(run_dir)
    out = []
    if (d / ROBOT_LOG).exists():
        with open(d / ROBOT_LOG, encoding="utf-8") as f:
            for line in f:
                try:
                    s = json.loads(line)
                except ValueError:
                    continue
                if s.get("kind") == "pose" and s.get("robot") == robot:
                    out.append((s["sim"], s["pose"][0], s["pose"][1]))
        if out:
            return out
    truth = recorded_result(d).get("truth") or {}
    traj = truth.get("trajectory") or []
    if isinstance(traj, dict):
        traj = traj.get(robot, [])
    return [(t, x, y) for t, x, y, *_ in traj]


def max_deviation(a: list[tuple[float, float, float]], b: list[tuple[float, float, float]]) -> tuple[float, float]:
    """How far apart the two trajectories are as paths: the largest distance from a point of either
    to the other's polyline (when each moved, in simulated time, differs between runs: see the
    module's doc), and the end poses' distance if larger; with the simulated time of the worst point of `a`."""
    if not a or not b:
        return math.inf, 0.0
    pa = np.array([[x, y] for _, x, y in a], float)
    pb = np.array([[x, y] for _, x, y in b], float)
    da, db = distance_to_polyline(pa, pb), distance_to_polyline(pb, pa)
    worst = max(float(da.max()), float(db.max()), float(np.linalg.norm(pa[-1] - pb[-1])))
    return worst, a[int(da.argmax())][0]


@dataclass
class Comparison:
    same: list[str] = field(default_factory=list)
    within: list[str] = field(default_factory=list)  # numbers that differ within their tolerance
    differ: list[str] = field(default_factory=list)
    deviation_m: float = 0.0

    @property
    def ok(self) -> bool:
        return not self.differ

    def text(self) -> str:
        lines = [("re-simulation matches the recording" if self.ok else "re-simulation DIFFERS from the recording")
                 + f" (trajectory within {self.deviation_m:.3f} m)"]
        lines += [f"  same:   {s}" for s in self.same]
        lines += [f"  within: {s}" for s in self.within]
        lines += [f"  DIFFER: {s}" for s in self.differ]
        return "\n".join(lines)

    def as_dict(self) -> dict:
        return {"ok": self.ok, "same": self.same, "within": self.within, "differ": self.differ,
                "trajectory_deviation_m": round(self.deviation_m, 4)}


def _numbers_close(a: float, b: float, rel: float = NUMBER_TOL) -> bool:
    return abs(a - b) <= max(0.05, rel * max(abs(a), abs(b)))


def _compare_value(name: str, old, new, c: Comparison) -> bool:
    """Structure and non-numeric values equal, numbers within NUMBER_TOL; False (noted) when not."""
    if isinstance(old, bool) or isinstance(new, bool) or not (isinstance(old, (int, float)) and isinstance(new, (int, float))):
        if isinstance(old, dict) and isinstance(new, dict) and set(old) == set(new):
            return all(_compare_value(f"{name}.{k}", old[k], new[k], c) for k in old)
        if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
            return all(_compare_value(f"{name}[{i}]", a, b, c) for i, (a, b) in enumerate(zip(old, new)))
        if isinstance(old, str) and isinstance(new, str) and old != new:
            if _NUMBER.sub("#", old) == _NUMBER.sub("#", new):
                pairs = list(zip(map(float, _NUMBER.findall(old)), map(float, _NUMBER.findall(new))))
                if all(_numbers_close(a, b) for a, b in pairs):
                    c.within.append(f"{name}: {new!r}, recorded {old!r}")
                    return True
        if old != new:
            c.differ.append(f"{name}: {_short(new)} now, {_short(old)} recorded")
            return False
        return True
    if old != new:
        if not _numbers_close(old, new):
            c.differ.append(f"{name}: {new} now, {old} recorded")
            return False
        c.within.append(f"{name}: {new}, recorded {old}")
    return True


def _short(v) -> str:
    s = json.dumps(v, default=str)
    return s if len(s) < 160 else s[:160] + "..."


def compare(old_dir: str | Path, new_dir: str | Path, robot: str, tolerance_m: float = TRAJECTORY_TOL_M) -> Comparison:
    old, new = recorded_result(old_dir), recorded_result(new_dir)
    c = Comparison()
    for key in ("seed", "house", "robot", "rapp", "command", "delivery", "scenario", "disturbances", "scheduled",
                "drive", "lived_in", "daylight", "link"):
        if key in old and _setting(key, old.get(key)) != _setting(key, new.get(key)):
            c.differ.append(f"{key}: {_short(new.get(key))} now, {_short(old.get(key))} recorded "
                            "(not a re-simulation of it)")
    knobs = [k for k in ("lived_in", "daylight", "link", "disturbances") if old.get(k)
             and _setting(k, old[k]) == _setting(k, new.get(k))]
    if knobs:
        c.same.append(f"the world's {', '.join(knobs)} as recorded")
    truth_old, truth_new = old.get("truth") or {}, new.get("truth") or {}
    for key in ("doors", "lamps"):
        if key in truth_old:
            (c.same if truth_old[key] == truth_new.get(key) else c.differ).append(
                f"the world's {key} drawn from the seed" + ("" if truth_old[key] == truth_new.get(key) else
                                                            f": {_short(truth_new.get(key))} now"))
    for key in ("ok", "stage", "state", "finished", "all_correct"):
        if key in old:
            if old[key] == new.get(key):
                c.same.append(f"{key}: {old[key]}")
            else:
                c.differ.append(f"{key}: {new.get(key)} now, {old[key]} recorded")
    if "reports" in old:
        before = len(c.differ)
        if _compare_value("reports", [_report(r) for r in old["reports"]], [_report(r) for r in new.get("reports", [])], c):
            c.same.append(f"{len(old['reports'])} reports" + ("" if before == len(c.differ) else ""))
    if "hazards" in old:
        _compare_hazards(old["hazards"], new.get("hazards", []), c)
    dev, at = max_deviation(trajectory(new_dir, robot), trajectory(old_dir, robot))
    c.deviation_m = dev
    if dev <= tolerance_m:
        c.same.append(f"trajectory: within {dev:.3f} m of the recorded one (tolerance {tolerance_m} m)")
    else:
        c.differ.append(f"trajectory: {dev:.3f} m from the recorded one at {at:.1f} s simulated "
                        f"(tolerance {tolerance_m} m)")
    return c


def _setting(key: str, value):
    """What of a recorded setting must be equal in its re-simulation: a link's faults, not what it did."""
    if key == "link" and isinstance(value, dict):
        return {k: v for k, v in value.items() if k in LINK_FAULTS}
    return value


def _report(r: dict) -> dict:
    return {"text": r.get("text", ""), "data": r.get("data", {})}


def _compare_hazards(old: list[dict], new: list[dict], c: Comparison) -> None:
    by_id = {h["id"]: h for h in new}
    truth = [{k: h.get(k) for k in ("id", "true_state", "true_angle")} for h in old]
    if truth == [{k: by_id.get(h["id"], {}).get(k) for k in ("id", "true_state", "true_angle")} for h in old]:
        c.same.append("the world's hazards drawn from the seed (true states and angles)")
    else:
        c.differ.append("the world's hazards: " + _short([{k: h.get(k) for k in ("id", "true_state", "true_angle")}
                                                         for h in new]) + " now")
    for h in old:
        n = by_id.get(h["id"])
        if n is None:
            c.differ.append(f"hazard {h['id']}: not checked now")
            continue
        if n.get("reported_state") != h.get("reported_state"):
            c.differ.append(f"hazard {h['id']}: reported {n.get('reported_state')} now, {h.get('reported_state')} recorded")
            continue
        a, b = h.get("estimated_angle"), n.get("estimated_angle")
        if a is not None and b is not None and a != b:
            (c.within if abs(a - b) <= ANGLE_TOL_DEG else c.differ).append(
                f"hazard {h['id']}: angle {b} now, {a} recorded (tolerance {ANGLE_TOL_DEG} deg)")
        else:
            c.same.append(f"hazard {h['id']}: {h.get('reported_state')}" + (f" at {a} deg" if a is not None else ""))


def write(out: str | Path, recorded: str | Path, c: Comparison) -> Path:
    path = Path(out) / "resim.json"
    path.write_text(json.dumps({"recording": str(recorded), **c.as_dict()}, indent=1))
    return path
