"""Lamp checks by the light of a time of day (issue 48.3), as the hazard RApp makes them.

Houses generated from seeds drawn at random (printed) and the full house; each at hours drawn at
random (with a night and a day hour in every house), windows glowing by day (robots/lighting.py),
lamps of several strengths. The robot arrives a few cm off each lamp's stand, turns its camera to the
lamp, takes the light check's frame at the RApp's low exposure (its camera's noise on) and the
Platform's light check decides, lamp on and off. The truth is the lamp's switch, not the room's light.

    .venv/bin/python -m scenarios.light_validation [--houses N | --seed-list S ...] [--robots nao ...]
"""
from __future__ import annotations

import argparse
import asyncio
import random
import sys
import time
from dataclasses import dataclass

import cv2
import numpy as np


from agents.services import hazard
from agents.services.images import encode_image
from ontology import robot_types
from ontology.robot import LookAtPoint, SetCameraParams
from ontology.services.hazard import LightCheck
from robots import RobotAPI, World
from robots.lighting import Daylight
from robots.pybullet_quiet import p

from .hazard_validation import ARRIVAL_M, ARRIVAL_RAD, rapp_params
from .home_setup import hazard_list, hazard_overrides

NIGHT, DAY = (21.0, 24.0 + 5.0), (9.0, 17.0)  # a house's two hours besides the random ones


@dataclass
class LampRow:
    house: str
    seed: int
    robot: str
    hour: float
    sky: float
    lamp: str
    strength: float
    on: bool
    level: int
    decided_on: bool
    window_share: float  # of the frame's pixels: a window (bright by day) in the check's view

    @property
    def right(self) -> bool:
        return self.decided_on == self.on


def hours_for(rng: random.Random, extra: int) -> list[float]:
    """A night hour, a day hour and `extra` hours anywhere in the day."""
    return [round(rng.uniform(*NIGHT) % 24.0, 2), round(rng.uniform(*DAY), 2)] + \
           [round(rng.uniform(0.0, 24.0), 2) for _ in range(extra)]


async def lamp_checks(house: str, seed: int, robot: str, hour: float, params: dict, rng: np.random.Generator) -> list[LampRow]:
    world = World.from_file(house, seed=seed, overrides=hazard_overrides(house, seed), render="inline",
                            daylight=Daylight(seed=seed, hour=hour))
    rows = []
    try:
        light = world.daylight or {}
        for spec in (h for h in hazard_list(world, house) if h.type == "lamp"):
            dx, dy = rng.normal(0.0, ARRIVAL_M, 2)
            pose = (spec.stand.x + dx, spec.stand.y + dy, spec.stand.theta + rng.normal(0.0, ARRIVAL_RAD))
            # it believes it stands on the stand (it aims from there), a few cm off it
            api = RobotAPI(world.add_robot(robot, name=f"{robot}-{spec.id}", pose=pose))
            await world.run(api.robot.odometry.set, (spec.stand.x, spec.stand.y, spec.stand.theta))
            await api.look_at_point(LookAtPoint(x=spec.look_at[0], y=spec.look_at[1], z=spec.look_at[2]))
            await api.set_camera_params(SetCameraParams(exposure=float(params["light_exposure"]), auto_exposure=False))
            for on in (True, False):
                await world.set_lamp(spec.id, on)
                img = await api.capture_array(resolution=params["light_resolution"])
                answer = hazard.light_check(LightCheck(image_b64=encode_image(cv2.cvtColor(img, cv2.COLOR_RGB2BGR)),
                                                       on_threshold=int(params["light_on_level"])), None)
                rows.append(LampRow(house, seed, robot, hour, light.get("sky", 0.0), spec.id,
                                    light.get("lamp_strength", {}).get(spec.id, 1.0), on, answer.light_level,
                                    answer.lamp_on, await world.run(window_share, world, api.robot, img.shape)))
            await world.run(api.robot.set_base_pose, -50.0, -50.0, 0.0)  # out of the next view
    finally:
        world.close()
    return rows


def window_share(world: World, robot, shape: tuple[int, ...]) -> float:
    """pybullet thread: the share of the frame's pixels on a window (a segmentation render)."""
    if not world.window_uids:
        return 0.0
    h, w = shape[:2]
    view, proj = next(iter(robot.cameras.values())).view_projection(w, h)
    seg = np.asarray(p.getCameraImage(w, h, view, proj, renderer=p.ER_TINY_RENDERER,
                                      physicsClientId=world.cid)[4]).reshape(h, w)
    return float(np.isin(seg, world.window_uids).mean())


def report(rows: list[LampRow], seeds: list[int]) -> list[str]:
    lines = [f"Generated houses from seeds drawn at random: {', '.join(map(str, seeds))}, and the full house "
             f"(seed {seeds[0]}).", "",
             "| robot | checks right | frames with a window (most of a frame) | lit: levels (dimmest lamp's) | unlit: levels "
             "| wrong (house/seed lamp @hour: level, strength, sky) |",
             "|---|---:|---:|---|---|---|"]
    for robot in sorted({r.robot for r in rows}):
        mine = [r for r in rows if r.robot == robot]
        lit, unlit = [r for r in mine if r.on], [r for r in mine if not r.on]
        dim = min(lit, key=lambda r: r.strength) if lit else None
        wrong = [f"{r.house[:3]}/{r.seed} {r.lamp} {'on' if r.on else 'off'} @{r.hour:g}: {r.level}, {r.strength:g}, "
                 f"{r.sky:.2f}" for r in mine if not r.right]
        seen = [r for r in mine if r.window_share > 0.0]
        lines.append(f"| {robot} | {sum(r.right for r in mine)}/{len(mine)} | "
                     f"{len(seen)} ({max((r.window_share for r in seen), default=0.0):.0%}) | "
                     f"{min(r.level for r in lit)}..{max(r.level for r in lit)} ({dim.level if dim else '-'} at "
                     f"{dim.strength if dim else '-'}) | {min(r.level for r in unlit)}..{max(r.level for r in unlit)} | "
                     f"{'; '.join(wrong)} |")
    return lines


async def validate(seeds: list[int], robots: list[str], extra_hours: int) -> list[LampRow]:
    params = rapp_params()
    rows: list[LampRow] = []
    for i, seed in enumerate(seeds):
        houses = ["generated"] + (["house"] if i == 0 else [])
        for house in houses:
            hours = hours_for(random.Random(seed), extra_hours)
            for robot in robots:
                for hour in hours:
                    got = await lamp_checks(house, seed, robot, hour, params, np.random.default_rng([seed, int(hour * 100)]))
                    rows += got
                    wrong = [r for r in got if not r.right]
                    print(f"{house} {seed} {robot} @{hour:05.2f}: {len(got) - len(wrong)}/{len(got)} right"
                          + (f"; wrong {' '.join(f'{r.lamp}:{r.on}:{r.level}' for r in wrong)}" if wrong else ""),
                          flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m scenarios.light_validation", description=__doc__.split("\n\n")[0])
    ap.add_argument("--houses", type=int, default=6, help="generated houses, seeds drawn at random (default 6)")
    ap.add_argument("--seed-list", type=int, nargs="+", help="these house seeds instead")
    ap.add_argument("--hours", type=int, default=2, help="random hours per house besides a night and a day one")
    ap.add_argument("--robots", nargs="+", choices=robot_types.names(), default=list(robot_types.names()))
    args = ap.parse_args(argv)
    seeds = args.seed_list or [random.SystemRandom().randrange(1, 100_000) for _ in range(args.houses)]
    print(f"seeds: {' '.join(map(str, seeds))}", flush=True)
    t0 = time.monotonic()
    rows = asyncio.run(validate(seeds, args.robots, args.hours))
    print("\n".join(report(rows, seeds)))
    print(f"{len(rows)} checks in {time.monotonic() - t0:.0f} s")
    return 0 if all(r.right for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
