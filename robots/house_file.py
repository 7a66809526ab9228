"""The house file (robots/houses/*.yaml, docs/houses.md) as a pydantic model: what `load_plan` reads,
typed, with each key's meaning, so a file is checked before a world is built from it and
docs/house.schema.json is generated from it (tests/test_house_file.py keeps both in step):

    python -m robots.house_file > docs/house.schema.json

`check(desc)` validates a description and returns what is wrong with it beyond the types (a door
whose gap cuts no wall, a hazard naming an unknown door, two landmarks with one text, ...).
"""
from __future__ import annotations

import json
import math
from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

Point = Annotated[list[float], Field(min_length=2, max_length=2)]
Color = Annotated[list[float], Field(min_length=3, max_length=3)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class WallSpec(_Strict):
    height: float = Field(default=2.4, gt=0, description="m")
    thickness: float = Field(default=0.1, gt=0, description="m")


class Opening(_Strict):
    """A doorway without a door: the wall is cut between the two points."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)
    from_: Point = Field(alias="from", description="x, y (m) of one end of the gap, on a wall")
    to: Point = Field(description="x, y (m) of the other end")


class Room(_Strict):
    name: str = Field(min_length=1)
    rect: list[float] = Field(min_length=4, max_length=4, description="x0, y0, x1, y1 (m), x0 < x1, y0 < y1")

    @model_validator(mode="after")
    def _ordered(self):
        x0, y0, x1, y1 = self.rect
        if not (x0 < x1 and y0 < y1):
            raise ValueError(f"room {self.name!r}: rect must be x0, y0, x1, y1 with x0 < x1 and y0 < y1")
        return self


DoorAngle = Union[Annotated[float, Field(ge=0, le=180)],
                  Annotated[list[Annotated[float, Field(ge=0, le=180)]], Field(min_length=2, max_length=2)]]


class Door(_Strict):
    """A hinged door in a wall. The wall is cut from the hinge `width` metres along `closed_yaw`."""

    id: str = Field(min_length=1)
    hinge: Point = Field(description="x, y (m) of the hinge, on a wall line")
    closed_yaw: float = Field(default=0.0, description="deg: the direction hinge -> latch when closed")
    width: float = Field(default=0.9, gt=0.3, le=3.0, description="m: the leaf and the gap it closes")
    opens: Literal["left", "right"] = Field(
        default="left", description="left: the leaf turns counter-clockwise seen from above; right: clockwise")
    angle: DoorAngle = Field(default=0.0, description="deg, 0 = closed, 90 = open; [lo, hi]: drawn from the seed")


class Lamp(_Strict):
    id: str = Field(min_length=1)
    x: float
    y: float
    z: float = Field(default=1.4, gt=0, description="m: the shade's centre")
    on: bool | Literal["random"] = Field(default="random", description="random: drawn from the seed")


class Furniture(_Strict):
    """A box standing on the floor."""

    name: str = "furniture"
    x: float
    y: float
    size: list[Annotated[float, Field(gt=0)]] = Field(min_length=3, max_length=3, description="sx, sy, sz (m)")
    yaw: float = Field(default=0.0, description="deg")
    color: Color = Field(default=[0.45, 0.5, 0.6], description="r, g, b in 0..1")


class Landmark(_Strict):
    """A QR panel on a wall. The robot's camera reads `text`; the Platform's home description keys the
    landmark map by it, with `size` (a RApp detects each code with its own size)."""

    id: str = Field(min_length=1)
    text: str | None = Field(default=None, description="the encoded text (default: the id)")
    x: float
    y: float
    z: float = Field(default=1.0, gt=0, description="m: the symbol's centre")
    yaw: float = Field(default=0.0, description="deg: the panel's normal, into the room")
    size: float = Field(default=0.25, gt=0.05, le=1.0, description="m: side of the QR symbol without quiet zone")


class RobotStart(_Strict):
    """Where a robot starts: a pose, a room (a free pose drawn from the seed) or a region."""

    pose: list[float] | None = Field(default=None, min_length=2, max_length=3, description="x, y (m), theta (deg)")
    room: str | None = None
    region: list[float] | None = Field(default=None, min_length=4, max_length=4, description="x0, y0, x1, y1 (m)")

    @model_validator(mode="after")
    def _one(self):
        given = [k for k in ("pose", "room", "region") if getattr(self, k) is not None]
        if len(given) > 1:
            raise ValueError(f"give one of pose, room, region (got {', '.join(given)})")
        return self


class Hazards(_Strict):
    """What the owner's home description lists (scenarios/home_setup.py): the doors checked and from
    which side, the lamps and the direction from the lamp into the room, the passage doors left open."""

    doors: dict[str, Literal["front", "swing"]] = {}
    lamps: dict[str, Point] = {}
    passages: list[str] = []


class Acoustics(_Strict):
    rt60_s: float = Field(default=0.0, ge=0, le=3.0, description="s: the rooms' reverberation time; 0 = none")


class HouseFile(_Strict):
    """A house description (metres; angles in degrees). Random choices (door angle ranges, lamps
    `random`, robots placed by room) are drawn from the run's seed (docs/houses.md)."""

    name: str = "house"
    wall: WallSpec = WallSpec()
    walls: list[Annotated[list[float], Field(min_length=4, max_length=4)]] = Field(
        min_length=1, description="segments x1, y1, x2, y2 (m); door and opening gaps are cut out")
    openings: list[Opening] = []
    rooms: list[Room] = []
    doors: list[Door] = []
    lamps: list[Lamp] = []
    furniture: list[Furniture] = []
    landmarks: list[Landmark] = []
    robots: dict[str, RobotStart] = {}
    hazards: Hazards | None = None
    acoustics: Acoustics | None = None


def schema() -> dict:
    return HouseFile.model_json_schema(by_alias=True)


def parse(desc) -> HouseFile:
    """The typed house; ValueError naming each wrong key (path: problem)."""
    if not isinstance(desc, dict):
        raise ValueError(f"a house file is a mapping of keys (name, walls, doors, ...), not {type(desc).__name__}")
    desc = {**desc, "lamps": [_yaml_on(lp) for lp in desc.get("lamps") or []]} if "lamps" in desc else desc
    try:
        return HouseFile.model_validate(desc)
    except ValidationError as e:
        lines = [f"{'.'.join(str(x) for x in err['loc']) or '(file)'}: {err['msg']}" for err in e.errors()]
        raise ValueError("; ".join(lines)) from None


def _yaml_on(lamp):
    """YAML 1.1 (PyYAML) reads the key `on` as True: give it back its name (robots/floorplan.py does too)."""
    if isinstance(lamp, dict) and True in lamp:
        lamp = {("on" if k is True else k): v for k, v in lamp.items()}
    return lamp


def _on_wall(p, walls, tolerance: float) -> bool:
    for x1, y1, x2, y2 in walls:
        length = math.hypot(x2 - x1, y2 - y1)
        if length == 0:
            continue
        ux, uy = (x2 - x1) / length, (y2 - y1) / length
        along = (p[0] - x1) * ux + (p[1] - y1) * uy
        across = abs((p[0] - x1) * uy - (p[1] - y1) * ux)
        if across <= tolerance and -tolerance <= along <= length + tolerance:
            return True
    return False


def check(desc) -> tuple[HouseFile, list[str]]:
    """The typed house and its problems beyond the types (an empty list: fine). ValueError on types."""
    house = parse(desc)
    t = house.wall.thickness
    problems = []

    def unique(kind, ids):
        seen = set()
        for i in ids:
            if i in seen:
                problems.append(f"{kind} {i!r} is given twice")
            seen.add(i)

    unique("door", [d.id for d in house.doors])
    unique("lamp", [lp.id for lp in house.lamps])
    unique("room", [r.name for r in house.rooms])
    unique("landmark text", [m.text or m.id for m in house.landmarks])
    for d in house.doors:
        yaw = math.radians(d.closed_yaw)
        latch = (d.hinge[0] + d.width * math.cos(yaw), d.hinge[1] + d.width * math.sin(yaw))
        if not (_on_wall(d.hinge, house.walls, t) and _on_wall(latch, house.walls, t)):
            problems.append(f"door {d.id!r}: its gap (hinge {d.hinge} along {d.closed_yaw:g} deg, {d.width:g} m) "
                            "is not on a wall line: no wall is cut for it")
        if isinstance(d.angle, list) and d.angle[0] > d.angle[1]:
            problems.append(f"door {d.id!r}: angle range {d.angle} is not [lo, hi]")
    for o in house.openings:
        if not (_on_wall(o.from_, house.walls, t) and _on_wall(o.to, house.walls, t)):
            problems.append(f"opening {o.from_} -> {o.to} is not on a wall line")
    for m in house.landmarks:
        if not _on_wall((m.x, m.y), house.walls, t):
            problems.append(f"landmark {m.id!r} at ({m.x:g}, {m.y:g}) does not hang on a wall")
    rooms = {r.name for r in house.rooms}
    for name, start in house.robots.items():
        if start.room is not None and start.room not in rooms:
            problems.append(f"robots.{name}: unknown room {start.room!r} (rooms: {', '.join(sorted(rooms)) or 'none'})")
    if house.hazards is not None:
        doors, lamps = {d.id for d in house.doors}, {lp.id for lp in house.lamps}
        for i in [*house.hazards.doors, *house.hazards.passages]:
            if i not in doors:
                problems.append(f"hazards: unknown door {i!r} (doors: {', '.join(sorted(doors)) or 'none'})")
        for i, v in house.hazards.lamps.items():
            if i not in lamps:
                problems.append(f"hazards: unknown lamp {i!r} (lamps: {', '.join(sorted(lamps)) or 'none'})")
            elif v[0] == 0 and v[1] == 0:
                problems.append(f"hazards.lamps.{i}: the direction into the room is zero")
    return house, problems


TEMPLATE = """\
# {name}: a house description (docs/houses.md; schema docs/house.schema.json). Metres, degrees.
# Check it and draw it:  rapp house check {file}
name: {name}
wall: {{height: 2.4, thickness: 0.1}}
walls:                       # segments x1, y1, x2, y2; door gaps are cut out of them
  - [0, 0, 6, 0]
  - [6, 0, 6, 4]
  - [6, 4, 0, 4]
  - [0, 4, 0, 0]
  - [3.5, 0, 3.5, 4]         # the inner wall with door d1
rooms:
  - {{name: living, rect: [0.05, 0.05, 3.45, 3.95]}}
  - {{name: bedroom, rect: [3.55, 0.05, 5.95, 3.95]}}
doors:                       # angle: degrees open (0 closed); [lo, hi] is drawn from the run's seed
  - {{id: d1, hinge: [3.5, 1.0], closed_yaw: 90, width: 0.9, opens: right, angle: [0, 90]}}
lamps:
  - {{id: l1, x: 0.4, y: 3.6, z: 1.4, on: random}}
furniture:
  - {{name: table, x: 1.0, y: 1.0, size: [0.8, 0.6, 0.75], color: [0.55, 0.4, 0.25]}}
landmarks:                   # QR panels on the walls, yaw = the normal into the room, size = symbol side
  - {{id: qr_1, text: "QR-1", x: 1.8, y: 3.95, z: 0.7, yaw: -90, size: 0.25}}
  - {{id: qr_2, text: "QR-2", x: 0.05, y: 2.0, z: 0.7, yaw: 0, size: 0.25}}
  - {{id: qr_3, text: "QR-3", x: 5.95, y: 1.5, z: 0.7, yaw: 180, size: 0.35}}
robots:
  nao: {{room: living}}
  elektron: {{pose: [2.2, 0.5, 90]}}
hazards:                     # what the owner's home description lists for the hazard checks
  doors: {{d1: front}}
  lamps: {{l1: [1, -1]}}
  passages: []
"""


def template(name: str, file: str = "") -> str:
    return TEMPLATE.format(name=name, file=file or f"{name}.yaml")


if __name__ == "__main__":
    print(json.dumps(schema(), indent=2))
