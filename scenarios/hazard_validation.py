"""Validation of the Platform's hazard checks on PyBullet renders: the door angle over 0..90 deg in
5 deg steps seen by both robots from the standing poses of the home description (both methods of
the door check), and the light level with the lamp on and off under three room-light levels (at the
low exposure the hazard RApp sets, and at the normal exposure for comparison).

    .venv/bin/python -m scenarios.hazard_validation [--houses N | --seed-list S ...] [--out docs/hazard-validation.md]

With --houses, also every door of N generated houses (seeds drawn at random, printed) from the stand
the hazard RApp chooses (view.py) and from the home description's, the robot arriving a few cm off.
"""
from __future__ import annotations

import argparse
import asyncio
import random
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from agents.services import hazard
from agents.services.images import encode_image
from ontology import robot_types
from ontology.manifest import load_manifest
from ontology.robot import GetCameraInfo, GetTransform, LookAtPoint, SetCameraParams
from ontology.services.hazard import DoorCheck, LightCheck
from robots import RobotAPI, World

from rapps.hazard_detection.hazard_detection.cloud import views_for
from rapps.hazard_detection.hazard_detection.models import DoorViews
from rapps.hazard_detection.hazard_detection.task import (camera_spec, door_geometry, door_look_point,
                                                          door_open_threshold)

from .home_setup import DOOR_OPEN_DEG, LAYOUTS, hazard_list, hazard_overrides, home_description

COMMAND = ".venv/bin/python -m scenarios.hazard_validation --houses 10 --out docs/hazard-validation.md"
RAPP_DIR = Path(__file__).resolve().parent.parent / "rapps" / "hazard_detection"
ROBOTS = robot_types.names()  # ontology/robot_types.py
ANGLES = tuple(range(0, 91, 5))
DOOR_VIEWS = (("house", "d_kitchen"), ("house", "d_bedroom"), ("small", "d1"))  # all the doors checked
ROOM_LIGHT = {"dim": 0.5, "as simulated": 1.0, "bright": 2.0}  # scale of the renderer's ambient + diffuse light
NORMAL_EXPOSURE = 1.0
HOUSE_NAMES = {"house": "full house", "small": "small flat"}


@dataclass
class DoorRow:
    robot: str
    house: str
    door: str
    side: str  # the home description's view: "front" (non-swing side) or "swing"
    true_deg: float
    image_deg: float
    geometry_deg: float
    geometry_method: str  # "image" when the geometry method found no leaf and the image answer came back


@dataclass
class LightRow:
    robot: str
    lamp: str
    room_light: str
    lamp_on: bool
    level_low: int  # at the RApp's low exposure
    level_normal: int  # at exposure 1.0
    lamp_on_low: bool  # the check's decision at the low exposure


@dataclass
class ViewRow:
    """One door check in a generated house: the robot arrived near a stand (a few cm and a degree off)
    and looked, with the leaf at `true_deg`."""

    seed: int
    robot: str
    door: str
    stand: str  # "chosen": the RApp's view (view.py, looking again while unsure); "home": the home's stand
    true_deg: float
    angle: float
    confidence: float
    looks: int
    right: bool


@dataclass
class Validation:
    doors: list[DoorRow] = field(default_factory=list)
    lights: list[LightRow] = field(default_factory=list)
    views: list[ViewRow] = field(default_factory=list)
    view_seeds: list[int] = field(default_factory=list)
    params: dict = field(default_factory=dict)
    seconds: float = 0.0


def rapp_params() -> dict:
    """The hazard RApp's parameters (resolution, exposure, thresholds): validated as deployed."""
    return dict(load_manifest(RAPP_DIR).params)


def _gray(rgb) -> str:
    return encode_image(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))


async def door_sweep(house: str, door_id: str, robot: str, params: dict) -> list[DoorRow]:
    """The robot at the door's standing pose aims its camera as the RApp does for each method (image:
    the hinge; geometry: the hazard's floor point); the leaf turns 0..90 deg."""
    world = World.from_file(house, seed=1, overrides={"doors": {door_id: 0.0}}, render="inline")
    try:
        spec = next(h for h in hazard_list(world, house) if h.id == door_id)
        api = RobotAPI(world.add_robot(robot, pose=(spec.stand.x, spec.stand.y, spec.stand.theta)))
        res = params["check_resolution"]
        answers: dict[str, list] = {}
        for method in ("image", "geometry"):
            x, y, z = door_look_point(spec, method)
            await api.look_at_point(LookAtPoint(x=x, y=y, z=z))
            K = (await api.get_camera_info(GetCameraInfo(resolution=res))).K
            T = (await api.get_transform(GetTransform(chain="camera", space="global"))).matrix
            geometry = door_geometry(K, T, spec) if method == "geometry" else None
            answers[method] = []
            for angle in ANGLES:
                await world.set_door(door_id, angle)
                image = _gray(await api.capture_array(resolution=res))
                # the checks keep no per-user state: no service context needed
                answers[method].append(hazard.door_check(DoorCheck(image_b64=image, method=method,
                                                                   geometry=geometry), None))
        side = LAYOUTS[house]["doors"][door_id]
        return [DoorRow(robot, house, door_id, side, float(angle), by_image.door_angle, by_geometry.door_angle,
                        by_geometry.method)
                for angle, by_image, by_geometry in zip(ANGLES, answers["image"], answers["geometry"])]
    finally:
        world.close()


async def light_sweep(robot: str, params: dict) -> list[LightRow]:
    """The robot at each lamp's standing pose of the full house, lamp on and off, three room lights."""
    house = "house"
    world = World.from_file(house, seed=1, render="inline")
    rows = []
    try:
        lamps = [h for h in hazard_list(world, house) if h.type == "lamp"]
        for spec in lamps:
            api = RobotAPI(world.add_robot(robot, name=f"{robot}-{spec.id}",
                                           pose=(spec.stand.x, spec.stand.y, spec.stand.theta)))
            await api.look_at_point(LookAtPoint(x=spec.look_at[0], y=spec.look_at[1], z=spec.look_at[2]))
            for name, scale in ROOM_LIGHT.items():
                for on in (True, False):
                    await world.set_lamp(spec.id, on)
                    levels = {}
                    world.light_scale = scale
                    for exposure in (float(params["light_exposure"]), NORMAL_EXPOSURE):
                        await api.set_camera_params(SetCameraParams(exposure=exposure, auto_exposure=False))
                        img = await api.capture_array(resolution=params["light_resolution"])
                        rgb = encode_image(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
                        levels[exposure] = hazard.light_check(
                            LightCheck(image_b64=rgb, on_threshold=int(params["light_on_level"])), None)
                    low = levels[float(params["light_exposure"])]
                    rows.append(LightRow(robot, spec.id, name, on, low.light_level,
                                         levels[NORMAL_EXPOSURE].light_level, low.lamp_on))
            await world.run(api.robot.set_base_pose, -50.0, -50.0, 0.0)  # out of the next view
    finally:
        world.close()
    return rows


VIEW_ANGLES = (0.0, 20.0, 35.0, 50.0, 65.0, 80.0, 90.0)  # the scenario draws closed or 20..90 deg
ARRIVAL_M, ARRIVAL_RAD = 0.03, 0.015  # how far off its stand a robot arrives (1 sigma; hazard runs: a few cm)


async def generated_door_checks(seed: int, robot: str, params: dict, rng) -> list[ViewRow]:
    """Every door hazard of the generated house `seed`: the robot checks it from the RApp's chosen view
    (moving on to the next view while a frame's confidence is below door_min_confidence, as the RApp
    does) and from the home description's stand, each reached a little off, the leaf at VIEW_ANGLES."""
    house, res = "generated", params["check_resolution"]
    world = World.from_file(house, seed=seed, overrides=hazard_overrides(house, seed), render="inline")
    rows, placed = [], 0
    try:
        info, _, _ = home_description(world, house, Path(tempfile.mkdtemp(prefix="views-")))
        probe = RobotAPI(world.add_robot(robot, name=f"{robot}-probe", pose=(-50.0, -50.0, 0.0)))
        K = (await probe.get_camera_info(GetCameraInfo(resolution=res))).K
        camera = camera_spec(K, res, (await probe.get_transform(GetTransform(chain="camera", space="robot"))).matrix)

        async def look(pose) -> object:  # the robot arrives near `pose`, looks at the hinge, checks
            nonlocal placed
            placed += 1
            off = (rng.normal(0, ARRIVAL_M), rng.normal(0, ARRIVAL_M), rng.normal(0, ARRIVAL_RAD))
            api = RobotAPI(world.add_robot(robot, name=f"{robot}-{placed}", pose=tuple(p + o for p, o in zip(pose, off))))
            try:
                await api.look_at_point(LookAtPoint(x=x, y=y, z=z))
                image = _gray(await api.capture_array(resolution=res))
                return hazard.door_check(DoorCheck(image_b64=image, method="image"), None)
            finally:
                await world.run(api.robot.set_base_pose, -50.0, -50.0 - placed, 0.0)  # out of the next view

        for spec in [h for h in info.hazards if h.type == "door"]:
            x, y, z = door_look_point(spec, "image")
            room = next((r for r in info.rooms if r.name == spec.room), None)
            views = [(v.x, v.y, v.theta) for v in views_for(DoorViews(
                door=spec.door, robot_side=[spec.stand.x, spec.stand.y], camera=camera, rooms=info.rooms,
                doors=info.doors, room=room, open_threshold_deg=float(params["door_open_image_deg"]))).views]
            home = (spec.stand.x, spec.stand.y, spec.stand.theta)
            for stand, poses in (("chosen", views or [home]), ("home", [home])):
                for angle in VIEW_ANGLES:
                    await world.set_door(spec.id, angle)
                    looks = []
                    for pose in poses:
                        looks.append(await look(pose))
                        if looks[-1].confidence >= float(params["door_min_confidence"]):
                            break
                    best = max(reversed(looks), key=lambda r: r.confidence)
                    right = (best.door_angle > door_open_threshold(params, "image")) == (angle > DOOR_OPEN_DEG)
                    rows.append(ViewRow(seed, robot, spec.id, stand, angle, best.door_angle, best.confidence,
                                        len(looks), right))
    finally:
        world.close()
    return rows


async def validate(view_seeds: list[int] = ()) -> Validation:
    t0 = time.monotonic()
    params = rapp_params()
    out = Validation(params=params, view_seeds=list(view_seeds))
    for house, door in DOOR_VIEWS:
        for robot in ROBOTS:
            out.doors += await door_sweep(house, door, robot, params)
    for robot in ROBOTS:
        out.lights += await light_sweep(robot, params)
    rng = np.random.default_rng(list(view_seeds) or [0])
    for seed in view_seeds:
        for robot in ROBOTS:
            rows = await generated_door_checks(seed, robot, params, rng)
            out.views += rows
            wrong = [f"{r.door}@{r.true_deg:g}({r.stand})" for r in rows if not r.right]
            print(f"house {seed} {robot}: {sum(r.right for r in rows)}/{len(rows)} right"
                  + (f"; wrong {' '.join(wrong)}" if wrong else ""), flush=True)
    out.seconds = time.monotonic() - t0
    return out


# ------------------------------------------------------------------------------------ report
def decided_open(row: DoorRow, attr: str, params: dict) -> bool:
    """The RApp's decision on this answer, with the threshold of the method that answered."""
    method = "image" if attr == "image_deg" else row.geometry_method
    return getattr(row, attr) > door_open_threshold(params, method)


def door_stats(rows: list[DoorRow], attr: str, params: dict) -> dict:
    errors = [abs(getattr(r, attr) - r.true_deg) for r in rows]
    # the scenario draws closed (0) or clearly open (20..90) doors; 5..15 deg are a grey zone
    scored = [r for r in rows if r.true_deg == 0 or r.true_deg >= 20]
    wrong = [r.true_deg for r in scored if decided_open(r, attr, params) != (r.true_deg > DOOR_OPEN_DEG)]
    return dict(mean=sum(errors) / len(errors), max=max(errors), correct=len(scored) - len(wrong), n=len(scored),
                wrong=wrong)


def door_table(v: Validation) -> list[str]:
    lines = []
    for house, door in DOOR_VIEWS:
        rows = {r: [d for d in v.doors if (d.house, d.door, d.robot) == (house, door, r)] for r in ROBOTS}
        side = rows[ROBOTS[0]][0].side
        lines += [f"### {door} ({HOUSE_NAMES[house]}, {side} view)", "",
                  "| true deg | " + " | ".join(f"{r} image | {r} geometry" for r in ROBOTS) + " |",
                  "|---:|" + "---:|---:|" * len(ROBOTS)]
        for i, angle in enumerate(ANGLES):
            cells = []
            for r in ROBOTS:
                d = rows[r][i]
                cells += [f"{d.image_deg:.1f}",
                          f"{d.geometry_deg:.1f}" + ("" if d.geometry_method == "geometry" else " (image)")]
            lines.append(f"| {angle} | " + " | ".join(cells) + " |")
        for label, key in (("mean abs error", "mean"), ("max abs error", "max")):
            cells = [f"{door_stats(rows[r], a, v.params)[key]:.1f}" for r in ROBOTS for a in ("image_deg", "geometry_deg")]
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
        cells = []
        for r in ROBOTS:
            for a in ("image_deg", "geometry_deg"):
                s = door_stats(rows[r], a, v.params)
                wrong = f" (wrong at {', '.join(f'{w:.0f}' for w in s['wrong'])})" if s["wrong"] else ""
                cells.append(f"{s['correct']}/{s['n']}{wrong}")
        lines += ["| open/closed right | " + " | ".join(cells) + " |", ""]
    return lines


def light_table(v: Validation) -> list[str]:
    low = v.params["light_exposure"]
    lines = [f"| robot | lamp | room light | lamp | level, exposure {low} | decision | level, exposure 1.0 |",
             "|---|---|---|---|---:|---|---:|"]
    for r in v.lights:
        ok = "right" if r.lamp_on_low == r.lamp_on else "**wrong**"
        lines.append(f"| {r.robot} | {r.lamp} | {r.room_light} | {'on' if r.lamp_on else 'off'} | {r.level_low} "
                     f"| {'on' if r.lamp_on_low else 'off'} ({ok}) | {r.level_normal} |")
    return lines


def light_summary(v: Validation) -> str:
    on = [r.level_low for r in v.lights if r.lamp_on]
    off = [r.level_low for r in v.lights if not r.lamp_on]
    on_n = [r.level_normal for r in v.lights if r.lamp_on]
    off_n = [r.level_normal for r in v.lights if not r.lamp_on]
    right = sum(r.lamp_on_low == r.lamp_on for r in v.lights)
    return (f"At exposure {v.params['light_exposure']}: lit lamps {min(on)}..{max(on)}, unlit {min(off)}..{max(off)}, "
            f"{right}/{len(v.lights)} decided right with the threshold {v.params['light_on_level']}. At exposure 1.0: "
            f"lit {min(on_n)}..{max(on_n)}, unlit {min(off_n)}..{max(off_n)}.")


DISCUSSION = """\
## Discussion

**Image-only method (the default, as the original).** It does not measure the door: it measures
the angle *in the image* between the best near-horizontal line (within 30 deg) of the left half and
that of the right half, with the camera aimed at where the door frame meets the floor, so that the
wall's floor line falls in one half and the leaf's in the other, and it answers 90 when a half has
no such line. What the table shows, and why:

- **Closed doors read 0 wherever the lines are found**: the leaf's floor line continues the wall's,
  and collinear lines stay collinear in any view, so a closed reading does not depend on where the
  robot stands. That makes the open/closed decision work with a small threshold
  (`door_open_image_deg`), not the 10 deg of the ground truth.
- **The reading is not the opening angle.** The leaf turns away from the camera and its floor line
  turns far less in the image than on the floor: about 0.45x the opening for the NAO and 0.7x for
  the Elektron from the front. Then, past 45-60 deg, the leaf's line is steeper than 30 deg, the
  half is empty and the answer jumps to 90. Mean errors of 13-45 deg are what the method gives,
  not noise; the number is usable only as "more or less open".
- **A far wall can win (NAO, small house, 65-90 deg).** Through the open door the bedroom's far
  wall meets the floor in a nearly horizontal line in the upper left of the image; with the leaf's
  line gone it is the best line of that half, and an open door reads about 3 deg: closed.
- **A steep view misses every line (Elektron, d_bedroom).** The swing-side standing pose looks at
  the wall at about 45 deg; from the Elektron's camera the floor lines lie at 32-33 deg in the
  image, just past the 30 deg limit, so both halves are empty and every door, closed ones included,
  reads 90: open. The NAO sees the same lines at about 21 deg and decides right.

The original relied on the robot standing straight in front of the door frame. The home
description's standing poses were chosen for the geometry method; the image-only method is only as
good as that pose. In the full-house scenario (doors d_kitchen and d_bedroom) this means: a closed
d_bedroom is reported open by an Elektron; every other case the scenario draws is decided right.
The standing pose is the owner's choice (`scenarios/home_setup.py`), not the method's.

**Geometry method (`method="geometry"`, not in the original).** It back-projects the segments to the
floor with the camera's intrinsics and pose and is told the door's hinge, closed direction and
width (prior knowledge the paper's method did not have). It is metric, within 3 deg from both views
and both robots, and decides every drawn case right. It is not a reproduction of the paper.

**Light level (as the original).** Regions, the surround rule (min and max over all nine squares and
the centre dropped; a centre brighter than all is thus dropped twice, as in the original code), x4,
clamp to 0..100, and the first channel of the BGR image (the original's `cv::mean(img)[0]`). The x4
saturates: in these clean renders a lit lamp reads 100 and an unlit one 0 at the low exposure the
RApp sets (`set_camera_params`, restored afterwards), under all three room lights. At the normal
exposure a bright room (x2) brings the walls close to the lamp's brightness and a lit lamp drops to
about 50: the margin the low exposure keeps. The room light is scaled in the renderer (ambient and
diffuse together); a lit lamp is emissive and does not change. Real cameras add noise, blooming and
other light sources: the camera's noise is simulated, blooming is not; windows by day and lamps
of several strengths come with `--daylight` (`python -m scenarios.light_validation`, docs/realism.md).

The robots stand exactly at the standing poses here; in a hazard run they arrive within a few
centimetres and about a degree, which leaves closed readings at 0 but moves lines near the 30 deg
limit across it.

**Where the robot stands (issue 42).** The tables above are from the home description's stands. In
generated houses nobody tuned for, that stand (1 m straight in front of the door, the NAO's camera
0.48 m high) loses the wide-open leaf's floor line, and the method takes the far wall's line of the
room beyond: an open door read as closed, with the lines it took far from where the camera looks
(confidence 0). The hazard RApp now chooses its stand (`rapps/hazard_detection/hazard_detection/
view.py`, on its Cloud Agent): a pinhole model of its own camera (intrinsics, height, offset) predicts
the image method's reading from each candidate stand round the hinge at every opening, with the walls
of the rooms the home description lists, the leaf hiding what is behind it, and the method's own
floor-line rule and score; it also has to be right with a cabinet standing beside the hinge or the
latch (furniture the description does not list). The model predicts the renders to within a few
degrees (`tests/services/test_hazard_validation.py`). What it picks: for the NAO mostly a stand 0.8-1 m
from the hinge a little off the door's axis, for the Elektron (camera 1.03 m high) the same or a
diagonal stand further off; from there a wide-open leaf either keeps a usable line that reads open, or
leaves its half without any line (90: open). A frame whose lines do not pass where the camera looks
(confidence below `door_min_confidence`) is looked at again from the next view; the most confident look
answers, and the report says how sure it is.
"""


def views_section(v: Validation) -> list[str]:
    """Door checks in generated houses: the RApp's chosen views against the home description's stands."""
    if not v.view_seeds:
        return []
    p = v.params
    lines = [
        "## Door checks in generated houses nobody tuned for",
        "",
        f"Houses generated from seeds drawn at random when the harness ran: {', '.join(map(str, v.view_seeds))} "
        f"(repeat: `--seed-list {' '.join(map(str, v.view_seeds))}`). Every door hazard, both robots, the image-only "
        f"method, the leaf at {', '.join(f'{a:g}' for a in VIEW_ANGLES)} deg, each robot placed {ARRIVAL_M * 100:g} cm and "
        f"{ARRIVAL_RAD:g} rad (1 sigma) off the stand, as it arrives in a run. \"chosen\": the stand the RApp picks "
        f"(view.py; a frame below confidence {p['door_min_confidence']} is looked at again from the next view, the "
        f"most confident look answers); \"home\": the home description's stand (`robots/house_gen.door_check_pose`), "
        f"one look.",
        "",
        "| robot | stand | checks right | wrong (door@deg: reading, confidence) | looks per check | mean confidence |",
        "|---|---|---:|---|---:|---:|",
    ]
    for robot in ROBOTS:
        for stand in ("chosen", "home"):
            rows = [r for r in v.views if r.robot == robot and r.stand == stand]
            if not rows:
                continue
            wrong = [f"{r.seed}/{r.door}@{r.true_deg:g}: {r.angle:g}, {r.confidence:.2f}" for r in rows if not r.right]
            lines.append(f"| {robot} | {stand} | {sum(r.right for r in rows)}/{len(rows)} | {'; '.join(wrong)} | "
                         f"{sum(r.looks for r in rows) / len(rows):.2f} | "
                         f"{sum(r.confidence for r in rows) / len(rows):.2f} |")
    return lines + [""]


def markdown(v: Validation) -> str:
    p = v.params
    head = [
        "# Hazard checks validated on PyBullet renders",
        "",
        f"Regenerate with `{COMMAND}` ({v.seconds:.0f} s on the shared 2-core machine).",
        "",
        "## Door angle",
        "",
        f"Each robot stands exactly at the standing pose the home description gives for the door "
        f"(`scenarios/home_setup.py`); the leaf is set to 0..90 deg; one "
        f"{p['check_resolution']} image per angle goes to the door check with each method (the "
        f"geometry method gets the camera's intrinsics and pose and the door's hinge, closed direction "
        f"and width). The camera is aimed as the hazard RApp aims it: at the hinge on the floor for the "
        f"image-only method (where the door frame meets the floor, as the original required), at the "
        f"hazard's floor point for the geometry method. Errors are |estimate - true| in degrees. "
        f"\"open/closed right\" applies the RApp's thresholds (open above {p['door_open_image_deg']} deg "
        f"image-only, {p['door_open_deg']} deg geometry) to the angles the scenario draws (closed, or "
        f"20..90 deg), truth: open above {DOOR_OPEN_DEG:g} deg. \"(image)\": the geometry method found "
        f"no leaf and the image-only answer came back.",
        "",
    ]
    light = [
        "## Light level",
        "",
        f"Each robot stands at the lamp's standing pose of the full house and looks at the shade; one "
        f"{p['light_resolution']} image at the RApp's exposure {p['light_exposure']} and one at 1.0, "
        f"lamp on and off, the renderer's room light scaled x{', x'.join(f'{s:g}' for s in ROOM_LIGHT.values())}.",
        "",
        light_summary(v),
        "",
    ]
    return "\n".join(head + door_table(v) + views_section(v) + light + light_table(v) + ["", DISCUSSION])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="hazard-validation", description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="write the Markdown here (default: print it)")
    ap.add_argument("--houses", type=int, default=0, metavar="N",
                    help="also check the doors of N generated houses, their seeds drawn at random")
    ap.add_argument("--seed-list", type=int, nargs="+", metavar="SEED", help="... these generated houses instead")
    args = ap.parse_args(argv)
    seeds = args.seed_list or sorted(random.SystemRandom().sample(range(1, 100_000), args.houses))
    if seeds:
        print(f"generated houses: {' '.join(map(str, seeds))} (repeat: --seed-list {' '.join(map(str, seeds))})",
              flush=True)
    text = markdown(asyncio.run(validate(seeds)))
    if args.out:
        Path(args.out).write_text(text)
        print(f"wrote {args.out}")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
