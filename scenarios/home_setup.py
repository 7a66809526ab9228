"""What the robot owner keeps on the Platform for the hazard-detection RApp: the occupancy map, the
QR landmark map and the list of possible hazards (where to stand, where to look), derived from the
house description. Door/lamp STATES are never part of it (except the passage door the owner leaves
open so the robot can move between rooms, which is drawn into the map).

    overrides = hazard_overrides("house", seed)          # seeded random doors (lamps: world seed)
    world = World.from_file("house", seed, overrides)
    info, png, yaml_text = home_description(world, "house", out_dir)
    upload_home(state, user, info, png, yaml_text)       # as the owner's earlier upload would
"""
from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np

from agents.services import home as home_service
from agents.services import navigation
from agents.services.context import ServiceContext, ServiceState
from ontology.services.home import DoorShape, HazardSpec, HomeInfo, LandmarkSpec, UploadHomeInfo
from ontology.errors import ErrorCode
from ontology.services.navigation import UploadMap
from robots.gridmap import OCCUPIED, build_grid_map

# per house: doors checked (and from which side), lamps checked, the passage door kept open
LAYOUTS = {
    "small": {"doors": {"d1": "front"}, "lamps": {"l1": (1.0, -1.0)}, "passage": None},
    "house": {"doors": {"d_kitchen": "front", "d_bedroom": "swing"},
              "lamps": {"l_living": (1.0, -1.0), "l_office": (1.0, -1.0)}, "passage": "d_living"},
}
DOOR_OPEN_DEG = 10.0  # ground truth: a door opened more than this is "open"


def hazard_overrides(house: str, seed: int) -> dict:
    """Seeded random door angles: closed (0) or clearly open (20..90 deg); the passage door 80..90."""
    layout = LAYOUTS[house]
    rng = np.random.default_rng([seed, 6])
    doors = {}
    for door_id in layout["doors"]:
        doors[door_id] = 0.0 if rng.random() < 0.5 else round(float(rng.uniform(20, 90)), 1)
    if layout["passage"]:
        doors[layout["passage"]] = round(float(rng.uniform(80, 90)), 1)
    lamps = {lamp_id: bool(rng.random() < 0.5) for lamp_id in layout["lamps"]}
    return {"doors": doors, "lamps": lamps}


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def door_hazard(door, side: str) -> HazardSpec:
    """Stand so that every leaf position is seen obliquely: in front of the wall (non-swing side)
    or diagonally on the swing side; look at the floor near the hinge."""
    h = np.asarray(door.hinge, float)
    c = np.array([math.cos(door.closed_yaw), math.sin(door.closed_yaw)])
    n = np.array([-c[1], c[0]]) * door.sign  # the side the leaf swings to
    if side == "front":
        stand, look = h + 0.2 * c - 1.0 * n, h + 0.35 * c
    else:
        stand, look = h + 1.3 * _unit(n - c), h + 0.3 * _unit(n + c)
    theta = math.atan2(look[1] - stand[1], look[0] - stand[0])
    return HazardSpec(id=door.id, type="door", stand=dict(x=stand[0], y=stand[1], theta=theta),
                      look_at=[look[0], look[1], 0.0],
                      door=DoorShape(hinge=list(h), closed_yaw_deg=math.degrees(door.closed_yaw), width_m=door.width))


def lamp_hazard(lamp, into_room: tuple[float, float], distance: float = 1.4) -> HazardSpec:
    stand = np.array([lamp.x, lamp.y]) + distance * _unit(into_room)
    theta = math.atan2(lamp.y - stand[1], lamp.x - stand[0])
    return HazardSpec(id=lamp.id, type="lamp", stand=dict(x=stand[0], y=stand[1], theta=theta),
                      look_at=[lamp.x, lamp.y, lamp.z])


def hazard_list(world, house: str) -> list[HazardSpec]:
    layout = LAYOUTS[house]
    doors = {d.id: d for d in world.plan.doors}
    lamps = {lp.id: lp for lp in world.plan.lamps}
    return ([door_hazard(doors[i], side) for i, side in layout["doors"].items()]
            + [lamp_hazard(lamps[i], d) for i, d in layout["lamps"].items()])


def landmark_specs(world) -> dict[str, LandmarkSpec]:
    return {m["text"]: LandmarkSpec(x=m["x"], y=m["y"], z=m["z"], yaw=m["yaw"], size_m=m["size"])
            for m in world.landmark_map()["landmarks"]}


def home_map(world, house: str):
    """The static map (walls, furniture) plus the passage door's leaf, as the owner would map it."""
    grid = build_grid_map(world.plan)
    passage = LAYOUTS[house]["passage"]
    if passage:
        door = next(d for d in world.plan.doors if d.id == passage)
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
    info = HomeInfo(home_id=home_id, map_id=f"{house}_map", hazards=hazard_list(world, house),
                    landmarks=landmark_specs(world))
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

    if house not in LAYOUTS:
        return f"no home description for house {house!r} (known: {', '.join(LAYOUTS)}); upload one"
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
