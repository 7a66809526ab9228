"""What the robot owner keeps on the Platform for the hazard-detection RApp: the occupancy map, the
QR landmark map and the list of possible hazards (where to stand, where to look), derived from the
house description. Door/lamp STATES are never part of it (except the passage doors the owner leaves
open so the robot can move between rooms, which are drawn into the map).

    overrides = hazard_overrides("house", seed)          # seeded random doors and lamps
    (house "generated": the house robots/house_gen.py generates from the seed, with its own layout)
    world = World.from_file("house", seed, overrides)
    info, png, yaml_text = home_description(world, "house", out_dir)
    upload_home(state, user, info, png, yaml_text)       # as the owner's earlier upload would
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import yaml

from agents.services import home as home_service
from agents.services import navigation
from agents.services.context import ServiceContext, ServiceState
from ontology.services.home import DoorCheckPose, DoorShape, DoorwaySpec, HazardSpec, HomeInfo, LandmarkSpec, RoomSpec, UploadHomeInfo
from ontology.errors import ErrorCode
from ontology.services.navigation import UploadMap
from robots import HOUSES as HOUSE_DIR
from robots.gridmap import OCCUPIED, build_grid_map
from robots.lived_in import LivedIn, live_in
from robots.house_gen import GENERATED, PASSAGE_OPEN_DEG, door_check_pose, generate, lamp_check_pose

# per hand-made house: doors checked (and from which side), lamps checked (and the direction into the
# room), the passage doors kept open; a generated house (and any description with a `hazards`
# section) brings its own
LAYOUTS = {
    "small": {"doors": {"d1": "front"}, "lamps": {"l1": (1.0, -1.0)}, "passages": []},
    "house": {"doors": {"d_kitchen": "front", "d_bedroom": "swing"},
              "lamps": {"l_living": (1.0, -1.0), "l_office": (1.0, -1.0)}, "passages": ["d_living"]},
}
HOUSES = (*LAYOUTS, GENERATED)  # the houses the scenarios can run in
DOOR_OPEN_DEG = 10.0  # ground truth: a door opened more than this is "open"


def _plan(world_or_plan):
    """The plan as the owner mapped it: a World's `mapped_plan` (robots/lived_in.py), else its plan."""
    return getattr(world_or_plan, "mapped_plan", None) or getattr(world_or_plan, "plan", world_or_plan)


def layout(house: str, world_or_plan=None, seed: int | None = None) -> dict:
    """The hazard layout of a house: LAYOUTS for the hand-made ones, else the description's `hazards`
    section (of the given world / plan, or of the house generated from `seed`)."""
    if house in LAYOUTS:
        return LAYOUTS[house]
    if world_or_plan is not None:
        hz = _plan(world_or_plan).hazards
    elif house == GENERATED and seed is not None:
        hz = generate(seed)["hazards"]
    else:
        hz = described_hazards(house)
    if not hz:
        raise KeyError(f"no hazard layout for house {house!r} (known: {', '.join(HOUSES)})")
    return {"doors": dict(hz.get("doors", {})), "lamps": {k: tuple(v) for k, v in hz.get("lamps", {}).items()},
            "passages": list(hz.get("passages", []))}


def described_hazards(house: str) -> dict:
    """The `hazards` section of a house file (a bare name in robots/houses, or a path); {} if none."""
    path = Path(house) if Path(house).exists() else HOUSE_DIR / f"{house}.yaml"
    if not path.is_file():
        return {}
    desc = yaml.safe_load(path.read_text()) or {}
    return dict(desc.get("hazards") or {}) if isinstance(desc, dict) else {}


def has_layout(house: str, world_or_plan=None) -> bool:
    return house in LAYOUTS or bool(world_or_plan is not None and _plan(world_or_plan).hazards)


def hazard_overrides(house: str, seed: int) -> dict:
    """Seeded random door angles: closed (0) or clearly open (20..90 deg); passage doors 80..90; lamps
    on or off. A generated house is generated from the same seed."""
    lay = layout(house, seed=seed)
    rng = np.random.default_rng([seed, 6])
    doors = {}
    for door_id in lay["doors"]:
        doors[door_id] = 0.0 if rng.random() < 0.5 else round(float(rng.uniform(20, 90)), 1)
    for door_id in lay["passages"]:
        doors[door_id] = round(float(rng.uniform(*PASSAGE_OPEN_DEG)), 1)
    lamps = {lamp_id: bool(rng.random() < 0.5) for lamp_id in lay["lamps"]}
    return {"doors": doors, "lamps": lamps}


def scenario_world(house: str, seed: int, lived_in: LivedIn | None = None, **world_kw):
    """The world of `house` at `seed`, the same in every scenario (`rapp run rapp`, hazard-detection,
    two-robots, the disturbance suite): where the house has a hazard layout (small, house, generated,
    or a file with a `hazards:` section) its hazard doors, passages and lamps are drawn by
    hazard_overrides; every other door and lamp from the house file's own ranges (robots/floorplan.py),
    also from `seed`. `lived_in`: the house changed since its map was made (robots/lived_in.py; the
    world's `lived_in` says how). `world_kw`: World.from_file's (rtf, disturbances, daylight, ...)."""
    from robots import World

    name = Path(house).stem if Path(house).stem in LAYOUTS else house  # robots/small.yaml is "small"
    try:
        overrides = hazard_overrides(name, seed)
    except KeyError:  # no hazard layout: the house file alone draws the world
        overrides = None
    edit = None if lived_in is None else (lambda mapped: lived_in_plan(mapped, name, lived_in))
    return World.from_file(house, seed=seed, overrides=overrides, lived_in=edit, **world_kw)


def lived_in_plan(mapped, house: str, knobs: LivedIn):
    """robots.lived_in.live_in with what must stay clear: the robots' start poses and the hazards'
    stands, reachable as they were on the map."""
    from ontology.robot_types import ROBOT_TYPES, widest_clearance_m

    lay = layout(house, mapped) if has_layout(house, mapped) else {"passages": []}
    radius = widest_clearance_m()
    starts = [tuple(mapped.start_pose(kind, kind, row.body_radius_m)[:2]) for kind, row in ROBOT_TYPES.items()]
    stands = [(h.stand.x, h.stand.y) for h in hazard_list(mapped, house)] if has_layout(house, mapped) else []
    return live_in(mapped, knobs, passages=lay["passages"], keep_clear=[*starts, *stands], clearance_m=radius)


def door_hazard(door, side: str) -> HazardSpec:
    """Stand so that every leaf position is seen obliquely (robots.house_gen.door_check_pose); look at
    the floor near the hinge."""
    stand, look = door_check_pose(door, side)
    theta = math.atan2(look[1] - stand[1], look[0] - stand[0])
    return HazardSpec(id=door.id, type="door", stand=dict(x=stand[0], y=stand[1], theta=theta),
                      look_at=[look[0], look[1], 0.0],
                      door=door_shape(door))


def door_shape(door) -> DoorShape:
    return DoorShape(hinge=list(door.hinge), closed_yaw_deg=math.degrees(door.closed_yaw), width_m=door.width,
                     opens="left" if door.sign > 0 else "right")


def doorway(plan, door) -> DoorwaySpec:
    """A door as the home description lists it: where and how wide (its shape, with the side it swings
    to), its rooms and a check pose from each side (door_check_pose, as the hazard list's doors)."""
    shape = door_shape(door)
    mid = (door.hinge[0] + 0.5 * door.width * math.cos(door.closed_yaw),
           door.hinge[1] + 0.5 * door.width * math.sin(door.closed_yaw))
    normal = (-math.sin(door.closed_yaw), math.cos(door.closed_yaw))
    rooms = [plan.room_at(mid[0] + s * 0.3 * normal[0], mid[1] + s * 0.3 * normal[1]) for s in (1, -1)]
    return DoorwaySpec(id=door.id, door=shape, rooms=[r for r in rooms if r],
                       checks=[door_check(plan, door, side) for side in ("front", "swing")])


def door_check(plan, door, side: str) -> DoorCheckPose:
    """The check pose of `door` on `side`, with its room and its clearance from walls and furniture
    (the door leaves' positions are the world's state, not the home's)."""
    h = door_hazard(door, side)
    statics = plan.obstacles(include_doors=False)
    clearance = min(b.distance(h.stand.x, h.stand.y) for b in statics) if statics else None
    return DoorCheckPose(side=side, stand=h.stand, look_at=h.look_at, room=plan.room_at(h.stand.x, h.stand.y),
                         clearance_m=None if clearance is None else round(clearance, 3))


def lamp_hazard(lamp, into_room: tuple[float, float], distance: float = 1.4) -> HazardSpec:
    stand = lamp_check_pose(lamp, into_room, distance)
    theta = math.atan2(lamp.y - stand[1], lamp.x - stand[0])
    return HazardSpec(id=lamp.id, type="lamp", stand=dict(x=stand[0], y=stand[1], theta=theta),
                      look_at=[lamp.x, lamp.y, lamp.z])


def hazard_list(world, house: str) -> list[HazardSpec]:
    """`world`: a World or its Plan."""
    plan = _plan(world)
    lay = layout(house, plan)
    doors = {d.id: d for d in plan.doors}
    lamps = {lp.id: lp for lp in plan.lamps}
    return ([door_hazard(doors[i], side) for i, side in lay["doors"].items()]
            + [lamp_hazard(lamps[i], d) for i, d in lay["lamps"].items()])


def landmark_specs(world) -> dict[str, LandmarkSpec]:
    """`world`: a World or its Plan."""
    plan = _plan(world)
    # a panel hangs on a wall: its room is the one 0.2 m in front of it
    return {m.text: LandmarkSpec(x=m.x, y=m.y, z=m.z, yaw=m.yaw, size_m=m.size,
                                 room=plan.room_at(m.x + 0.2 * math.cos(m.yaw), m.y + 0.2 * math.sin(m.yaw)))
            for m in plan.landmarks}


def home_map(world, house: str):
    """The static map (walls, furniture) plus the passage doors' leaves, as the owner would map it
    (`world`: a World or its Plan)."""
    plan = _plan(world)
    grid = build_grid_map(plan)
    for passage in layout(house, plan)["passages"]:
        door = next(d for d in plan.doors if d.id == passage)
        leaf = door.leaf_box()
        leaf = replace(leaf, sy=max(leaf.sy, 2 * grid.resolution))
        pts = leaf.corners()
        h = grid.image.shape[0]
        px = (pts[:, 0] - grid.origin[0]) / grid.resolution - 0.5
        py = h - (pts[:, 1] - grid.origin[1]) / grid.resolution - 0.5
        cv2.fillPoly(grid.image, [np.round(np.stack([px, py], 1) * 16).astype(np.int32)], OCCUPIED,
                     lineType=cv2.LINE_8, shift=4)
    return grid


def home_description(world, house: str, out_dir, home_id: str = "home") -> tuple[HomeInfo, bytes, str]:
    """HomeInfo plus the map as PNG bytes and map_server YAML text (also written to out_dir)."""
    png, yml = home_map(world, house).save(out_dir, f"{house}_map")
    plan = _plan(world)
    hazards = [h.model_copy(update={"room": plan.room_at(*(h.look_at[:2] if h.type == "lamp" else (h.stand.x, h.stand.y)))})
               for h in hazard_list(world, house)]
    info = HomeInfo(home_id=home_id, map_id=f"{house}_map", hazards=hazards, landmarks=landmark_specs(world),
                    rooms=[RoomSpec(name=r.name, rect=list(r.rect)) for r in plan.rooms],
                    doors=[doorway(plan, d) for d in plan.doors])
    return info, png.read_bytes(), yml.read_text()


def upload_home(state: ServiceState, user: str, info: HomeInfo, png: bytes, yaml_text: str) -> None:
    """Store map and home description for `user` through the Platform's own service code."""
    import base64

    ctx = ServiceContext(user=user, state=state)
    navigation.upload_map(UploadMap(map_id=info.map_id, png_b64=base64.b64encode(png).decode(),
                                    yaml_text=yaml_text), ctx)
    home_service.upload_info(UploadHomeInfo(info=info), ctx)


async def upload_home_over_xmpp(agent, platform: str, token: str, info: HomeInfo, png: bytes,
                                yaml_text: str) -> None:
    """The same upload as the owner's app sends it: map, then home description, as Platform
    service requests with the owner's token (deployments: `rapp agent core --house`,
    `rapp platform upload-home`)."""
    import base64

    await agent.request(platform, UploadMap(token=token, map_id=info.map_id, yaml_text=yaml_text,
                                            png_b64=base64.b64encode(png).decode()), timeout=30.0)
    await agent.request(platform, UploadHomeInfo(token=token, info=info), timeout=30.0)


async def ensure_home(core, world, house: str, out_dir) -> str:
    """Upload the home description of `house` for the Core's owner unless the Platform has one:
    what the owner does once before asking for hazard checks. Returns what was done."""
    from agents.errors import RequestError
    from ontology.services.home import GetHomeInfo

    if not has_layout(house, world):
        return f"no home description for house {house!r} (known: {', '.join(HOUSES)}); upload one"
    token = await core.fresh_token()
    try:
        await core.request(core.platform, GetHomeInfo(token=token, home_id="home"))
        return f"home of {core.user} already on the Platform"
    except RequestError as e:
        if e.code != ErrorCode.UNKNOWN_HOME:
            raise
    info, png, yaml_text = home_description(world, house, out_dir)
    await upload_home_over_xmpp(core, core.platform, token, info, png, yaml_text)
    return f"uploaded the home description of {house!r} for {core.user}"
