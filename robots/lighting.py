"""Light as it is at a time of day (issue 48.3): daylight through windows, lamps of several strengths.

Without it (the default) every room has the same studio light and every lamp the same output, so a
light check only has to tell a glowing shade from a wall. With it, `with_daylight` gives the plan:
- windows in the outside walls, one per room side on the outside (placed clear of door gaps and QR
  labels); by day a window glows with the sky's radiance, up to WINDOW_RADIANCE times a lit white
  wall at a clear noon, far brighter than most lamps; at night it is dark glass;
- the room's ambient and diffuse light following the sky (ROOM_LIGHT_NIGHT of the studio light at
  night, all of it at a clear noon): a lit lamp's own light on the room is not modelled (one
  directional light in TinyRenderer);
- each lamp a strength (STRENGTHS, seeded): a dim bedside lamp glows at a third of a strong one.
The light check's truth stays "the lamp is on" (World.ground_truth), whatever the room looks like.

    plan, info = with_daylight(plan, Daylight(seed=3, hour=18.5))   # info: for the run's result.json
"""
from __future__ import annotations

import math
import zlib
from dataclasses import asdict, dataclass, replace

import numpy as np

from .floorplan import Box, Plan

LAMP_RADIANCE = 4.0  # a lit lamp's shade at full strength, times a lit white wall
LAMP_ON_COLOR = (1.0, 0.96, 0.78)
LAMP_OFF_COLOR = (0.22, 0.22, 0.23)
WINDOW_RADIANCE = 6.0  # a window at a clear noon, times a lit white wall
SKY_COLOR = (0.80, 0.90, 1.00)
NIGHT_GLASS = (0.07, 0.08, 0.10)  # a window with nothing lit behind it
ROOM_LIGHT_NIGHT = 0.55  # the rooms' ambient + diffuse light at night, of the studio light's
STRENGTHS = (0.3, 1.0)  # lamps' relative output, drawn uniformly
SILL_M, TOP_M = 0.9, 2.05
WINDOW_W = 1.2
CLEAR_OF_CODE_M = 0.3  # a window's edge this far from a QR label on its wall


@dataclass(frozen=True)
class Daylight:
    """The scenario's time of day (None: drawn from the seed, 6:00-23:00) and its seed (overcast,
    lamp strengths)."""
    seed: int = 0
    hour: float | None = None

    def describe(self) -> dict:
        return asdict(self)


def sky_level(hour: float, overcast: float) -> float:
    """0 (night) .. 1 (a clear noon): the sun's height over a 6:00-20:00 day, dimmed by cloud."""
    day = (hour % 24.0 - 6.0) / 14.0
    if not 0.0 < day < 1.0:
        return 0.0
    return float(math.sin(math.pi * day) * (1.0 - 0.7 * overcast))


def room_light(sky: float | None) -> float:
    """Scale of the renderer's ambient and diffuse light (None: the studio light, 1)."""
    return 1.0 if sky is None else ROOM_LIGHT_NIGHT + (1.0 - ROOM_LIGHT_NIGHT) * sky


def lamp_radiance(strength: float) -> tuple[float, float, float]:
    """A lit lamp's shade (its light on the room is not modelled)."""
    return tuple(c * LAMP_RADIANCE * strength for c in LAMP_ON_COLOR)  # type: ignore[return-value]


def window_radiance(sky: float) -> tuple[float, float, float] | None:
    """A window's radiance by day (None at night: plain dark glass)."""
    if sky < 0.02:
        return None
    return tuple(c * WINDOW_RADIANCE * sky for c in SKY_COLOR)  # type: ignore[return-value]


def with_daylight(plan: Plan, knobs: Daylight) -> tuple[Plan, dict]:
    """The plan lit at the knobs' time of day, and what that is (for the run's result)."""
    rng = np.random.default_rng([knobs.seed, zlib.crc32(b"daylight"), zlib.crc32(plan.name.encode())])
    hour = float(rng.uniform(6.0, 23.0)) if knobs.hour is None else float(knobs.hour) % 24.0
    overcast = float(rng.uniform(0.0, 1.0))
    sky = sky_level(hour, overcast)
    lamps = [replace(lp, strength=round(float(rng.uniform(*STRENGTHS)), 2)) for lp in plan.lamps]
    windows = outside_windows(plan)
    info = {"hour": round(hour, 2), "overcast": round(overcast, 2), "sky": round(sky, 3),
            "windows": len(windows), "lamp_strength": {lp.id: lp.strength for lp in lamps},
            "knobs": knobs.describe()}
    return replace(plan, lamps=lamps, windows=windows, sky=sky), info


def outside_windows(plan: Plan) -> list[Box]:
    """One window per room side that lies on the house's outside wall, in a stretch of wall (not a
    door gap) clear of QR labels; none where no such stretch is wide enough."""
    x0, y0, x1, y1 = plan.bounds
    t = plan.wall_thickness
    out: list[Box] = []
    for room in plan.rooms:
        rx0, ry0, rx1, ry1 = room.rect
        sides = [((rx0, y0 + t / 2), (rx1, y0 + t / 2), ry0 - y0 < 2 * t),  # south, along x
                 ((rx0, y1 - t / 2), (rx1, y1 - t / 2), y1 - ry1 < 2 * t),
                 ((x0 + t / 2, ry0), (x0 + t / 2, ry1), rx0 - x0 < 2 * t),  # west, along y
                 ((x1 - t / 2, ry0), (x1 - t / 2, ry1), x1 - rx1 < 2 * t)]
        for a, b, outside in sides:
            if outside:
                box = _window_on(plan, a, b, f"window:{room.name}:{len(out)}")
                if box is not None:
                    out.append(box)
    return out


def _window_on(plan: Plan, a: tuple[float, float], b: tuple[float, float], name: str) -> Box | None:
    length = math.dist(a, b)
    width = min(WINDOW_W, 0.5 * length)
    if width < 0.5:
        return None
    ux, uy = (b[0] - a[0]) / length, (b[1] - a[1]) / length
    t = plan.wall_thickness
    for shift in (0.0, 0.25, -0.25, 0.5, -0.5, 0.75, -0.75):
        s = length / 2 + shift * (length - width) / 2
        ends = [(a[0] + ux * (s + k * width / 2), a[1] + uy * (s + k * width / 2)) for k in (-1, 0, 1)]
        walled = all(any(w.distance(x, y) < 1e-3 for w in plan.walls) for x, y in ends)
        coded = any(abs((m.x - a[0]) * uy - (m.y - a[1]) * ux) < 2 * t
                    and abs((m.x - a[0]) * ux + (m.y - a[1]) * uy - s) < width / 2 + m.size / 2 + CLEAR_OF_CODE_M
                    for m in plan.landmarks)
        if walled and not coded:
            cx, cy = ends[1]
            return Box(name, cx, cy, width, t + 0.012, TOP_M - SILL_M, math.atan2(uy, ux), SILL_M, NIGHT_GLASS)
    return None
