"""Generated houses (robots/house_gen.py): deterministic per seed, 3-8 rooms, every hazard's check pose
reachable by the Platform's planner for both robots, QR landmarks by the installer's rule and seen
from every check pose, and a PyBullet world built from one whose camera decodes them."""
from __future__ import annotations

import base64
import math

import cv2
import numpy as np
import pytest

from agents.services import localization
from agents.services.context import ServiceContext, ServiceState
from agents.services.navigation import plan_path_2d, upload_map
from ontology.services.common import Pose2D
from ontology.services.navigation import PLAN_FOUND, PlanPath2D, UploadMap
from ontology.robot import LookAtPoint
from robots import RobotAPI, World
from robots.floorplan import load_plan
from robots.gridmap import OCCUPIED
from robots.house_gen import (GENERATED, HAZARD_W, PASSAGE_W, QR_SIZE, QR_SPACING, QR_Z, WALL_T,
                              generate)
from scenarios.home_setup import hazard_list, hazard_overrides, home_map, landmark_specs

SEEDS = range(20)


def plan_of(seed: int):
    return load_plan(generate(seed), seed, hazard_overrides(GENERATED, seed))


def test_same_seed_same_house_other_seeds_other_houses():
    assert generate(3) == generate(3)
    first = generate(3)
    first["rooms"].clear()  # a fresh dict each call: a caller's change does not leak into the next
    assert generate(3)["rooms"]
    assert len({repr(generate(s)["walls"]) for s in range(6)}) == 6
    assert hazard_overrides(GENERATED, 3) == hazard_overrides(GENERATED, 3)


@pytest.mark.parametrize("seed", SEEDS)
def test_rooms_tile_the_footprint(seed):
    desc = generate(seed)
    rooms = [r["rect"] for r in desc["rooms"]]
    assert 3 <= len(rooms) <= 8
    assert len({r["name"] for r in desc["rooms"]}) == len(rooms)
    xs = [v for w in desc["walls"] for v in w[0::2]]
    ys = [v for w in desc["walls"] for v in w[1::2]]
    inner = (max(xs) - min(xs) - WALL_T) * (max(ys) - min(ys) - WALL_T)
    area = sum((x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in rooms)
    assert area < inner + 1e-6  # the rooms' interiors plus the inner walls make the footprint
    for x0, y0, x1, y1 in rooms:
        assert min(x1 - x0, y1 - y0) >= 3.0 - WALL_T - 1e-6
    for i, a in enumerate(rooms):  # no overlaps
        for b in rooms[i + 1:]:
            assert a[2] <= b[0] or b[2] <= a[0] or a[3] <= b[1] or b[3] <= a[1], (a, b)


@pytest.mark.parametrize("seed", SEEDS)
def test_every_check_pose_reachable_by_the_planner(seed, tmp_path):
    """The home description's map (static obstacles and the passage doors at their drawn angles) and
    the Platform's A*: from each robot's start to every hazard's check pose, through doors wide enough
    for the Elektron."""
    plan = plan_of(seed)
    hazards = hazard_list(plan, GENERATED)
    lay = plan.hazards
    assert lay["doors"] and lay["lamps"], "a hazard door and a lamp in every house"
    assert {h.id for h in hazards} == set(lay["doors"]) | set(lay["lamps"])
    assert all(plan.room_at(h.stand.x, h.stand.y) for h in hazards)
    for d in plan.doors:
        assert d.width >= (PASSAGE_W if d.id in lay["passages"] else HAZARD_W[0])
        assert d.id in lay["doors"] or d.id in lay["passages"]
    png, yml = home_map(plan, GENERATED).save(tmp_path, "map")
    state = ServiceState(work_dir=tmp_path)
    ctx = ServiceContext(user="owner", state=state)
    upload_map(UploadMap(map_id="m", png_b64=base64.b64encode(png.read_bytes()).decode(),
                         yaml_text=yml.read_text()), ctx)
    for kind in ("nao", "elektron"):
        x, y, th = plan.start_pose(kind, kind, 0.3)
        start = Pose2D(x=x, y=y, theta=th)
        for h in hazards:
            reply = plan_path_2d(PlanPath2D(robot_type=kind, map_id="m", start=start, goal=h.stand), ctx)
            assert reply.plan_found == PLAN_FOUND, (seed, kind, h.id, reply.reason)


def _visible(grid, landmarks, x, y, max_m=4.0, max_angle_deg=60.0) -> list:
    """Landmarks seen from (x, y): near enough, not too oblique, no occupied map cell on the line."""
    seen = []
    for m in landmarks:
        v = np.array([x - m.x, y - m.y])
        dist = float(np.linalg.norm(v))
        if dist > max_m or v @ (math.cos(m.yaw), math.sin(m.yaw)) < dist * math.cos(math.radians(max_angle_deg)):
            continue
        samples = [(m.x + t * v[0], m.y + t * v[1]) for t in np.linspace(0.15 / dist, 1, int(dist / 0.02))]
        if all(grid.value_at(px, py) != OCCUPIED for px, py in samples):
            seen.append(m)
    return seen


@pytest.mark.parametrize("seed", SEEDS)
def test_landmarks_follow_the_installer_rule(seed):
    """Every code: 0.35 m, centre 0.7 m high, on a wall face, facing into a room, and at most 2 m from
    its neighbour on the same wall unless a door, furniture or a lamp is between. From each check pose
    and each start pose two codes at least 0.5 m apart are in view within 4 m."""
    plan = plan_of(seed)
    grid = home_map(plan, GENERATED)
    assert plan.landmarks and len({m.text for m in plan.landmarks}) == len(plan.landmarks)
    faces: dict[tuple, list] = {}
    for m in plan.landmarks:
        assert (m.size, m.z) == (QR_SIZE, QR_Z)
        nx, ny = round(math.cos(m.yaw)), round(math.sin(m.yaw))
        assert grid.value_at(m.x - 0.03 * nx, m.y - 0.03 * ny) == OCCUPIED, m.id  # on the wall
        assert plan.room_at(m.x + 0.3 * nx, m.y + 0.3 * ny), m.id  # facing into a room
        along = m.y if nx else m.x
        faces.setdefault((nx, ny, round(m.x if nx else m.y, 3)), []).append(along)
    blockers = ([(d.hinge, d.width) for d in plan.doors] + [((lp.x, lp.y), 0.4) for lp in plan.lamps]
                + [(np.add(o["from"], o["to"]) / 2, math.dist(o["from"], o["to"]) / 2)
                   for o in generate(seed)["openings"]])
    for (nx, ny, at), spots in faces.items():
        spots.sort()
        for a, b in zip(spots, spots[1:]):
            if b - a <= QR_SPACING + 0.6 + 1e-6:
                continue
            mid = ((at, (a + b) / 2) if nx else ((a + b) / 2, at))
            between = [f for f in plan.furniture if f.distance(*mid) < (b - a) / 2 + 0.5]
            near = [p for p, w in blockers if math.dist(p, mid) < (b - a) / 2 + w + 0.5]
            assert between or near, (seed, at, a, b)
    poses = [(h.stand.x, h.stand.y) for h in hazard_list(plan, GENERATED)]
    poses += [plan.start_pose(k, k, 0.3)[:2] for k in ("nao", "elektron")]
    for x, y in poses:
        seen = _visible(grid, plan.landmarks, x, y)
        spread = max((math.dist((a.x, a.y), (b.x, b.y)) for a in seen for b in seen), default=0.0)
        assert len(seen) >= 2 and spread > 0.5, (seed, (x, y), [m.id for m in seen])


async def test_world_of_a_generated_house_shows_decodable_codes():
    """The PyBullet world of a generated house has the seeded door angles and lamp states, and from a
    door's check pose the robot's camera, at the RApp's localization resolution, decodes the codes the
    home description lists in view."""
    seed = 4
    overrides = hazard_overrides(GENERATED, seed)
    with World.from_file(GENERATED, seed=seed, overrides=overrides, render="inline") as world:
        truth = world.ground_truth()
        assert truth.doors == pytest.approx(overrides["doors"])
        assert {i: truth.lamps[i] for i in overrides["lamps"]} == overrides["lamps"]
        door = next(h for h in hazard_list(world, GENERATED) if h.type == "door")
        api = RobotAPI(world.add_robot("nao", pose=(door.stand.x, door.stand.y, door.stand.theta)))
        landmarks = landmark_specs(world)
        in_view = sorted(_visible(home_map(world, GENERATED), world.plan.landmarks, door.stand.x, door.stand.y),
                         key=lambda m: math.dist((m.x, m.y), (door.stand.x, door.stand.y)))[:3]
        decoded = set()
        for m in in_view:
            await api.look_at_point(LookAtPoint(x=m.x, y=m.y, z=m.z))
            image = await api.capture_array(resolution="1280x960")
            decoded |= {text for text, _ in localization.detect_qr(cv2.cvtColor(image, cv2.COLOR_RGB2BGR))}
        assert decoded <= set(landmarks)
        assert len(decoded & {m.text for m in in_view}) >= 2, (decoded, [m.text for m in in_view])


def _installer_spots_of_the_full_house() -> tuple[list[dict], list]:
    """The installer's rule (house_gen.add_landmarks) applied to the hand-made house's rooms the robots
    walk through (living room, hall, office), and the house's own codes."""
    import yaml

    from robots.house_gen import Draft, Link, Room, add_landmarks
    from robots.world import HOUSES

    h = yaml.safe_load((HOUSES / "house.yaml").read_text())
    t = h["wall"]["thickness"] / 2  # the file's rooms are inside the walls, the rule's on their centre lines
    rooms = [Room(r["name"], (r["rect"][0] - t, r["rect"][1] - t, r["rect"][2] + t, r["rect"][3] + t))
             for r in h["rooms"] if r["name"] in ("living", "hall", "office")]
    links = []
    for d in h["doors"]:
        (hx, hy), yaw = d["hinge"], math.radians(d["closed_yaw"])
        end = (hx + d["width"] * math.cos(yaw), hy + d["width"] * math.sin(yaw))
        horizontal = abs(math.cos(yaw)) > 0.5
        links.append(Link("hazard", 0, 0, "y" if horizontal else "x", hy if horizontal else hx,
                          min(hx, end[0]) if horizontal else min(hy, end[1]), d["width"], door={"hinge": [hx, hy]}))
    for o in h["openings"]:
        (ax, ay), (bx, by) = o["from"], o["to"]
        links.append(Link("opening", 0, 0, "y", ay, min(ax, bx), abs(bx - ax)) if ay == by
                     else Link("opening", 0, 0, "x", ax, min(ay, by), abs(by - ay)))
    draft = Draft(np.random.default_rng(0), rooms, h["walls"], links, [{"x": lp["x"], "y": lp["y"]} for lp in h["lamps"]],
                  {}, h["furniture"])
    return add_landmarks(draft), h["landmarks"]


def test_the_full_house_follows_the_installer_rule_where_robots_walk():
    """Every spot where the rule would put a code has one of the house's within about one spacing (the
    hand-made walls are spaced a little differently). The living room's east wall had none for 5.75 m,
    between the kitchen door and the TV stand: a NAO walked 2 m there with no code in view."""
    spots, codes = _installer_spots_of_the_full_house()
    assert len(spots) > 40
    far = [(s["id"], s["x"], s["y"]) for s in spots
           if min(math.hypot(s["x"] - c["x"], s["y"] - c["y"]) for c in codes) > 1.1]
    assert not far, f"the rule puts codes where the house has none: {far}"
