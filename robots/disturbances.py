"""Things that move in the simulated house on a timeline of simulation time: a person walking a route,
a door someone opens or closes, an object dropped on the floor (issue 18, the base of a disturbance suite).

A scenario file (YAML) lists them under `disturbances:`; other keys (e.g. `speech:`) belong to other parts
of the run. Times are simulation seconds from the world's start, positions metres in the house frame:

    disturbances:
      - {kind: person, id: visitor, speed: 0.9, start: [2, 4], loop: false,
         route: [[4.6, 1.45], [3.0, 1.45], {x: 2.2, y: 2.9, pause: 6}]}    # pause: stands still there (s)
      - {kind: door, door: d1, at: 1.0, angle: 90, duration: 1.5}          # from its angle then, linearly
      - {kind: box, id: toy, at: 12, position: [2.0, 2.0], size: [0.3, 0.2, 0.15], drop_height: 0.8}
      - {kind: touch, robot: nao, sensor: head_middle, at: 20, seconds: 0.5}   # someone pats its head

A person stands at the first waypoint until `start`, walks the route at `speed` (pausing where a waypoint
says so, and, unless `yields: false`, while a robot stands in their way) and stays at the last one; with `loop` it walks back to the first and goes round again (a wait at
the end is the last waypoint's `pause`). A box is absent before `at`, then falls from `drop_height` (free
fall, no bounce) to the floor. A number written [lo, hi] (speed, start, at) is drawn once from a generator
seeded by the world's seed and the disturbance's id: the same seed gives the same run.

    world = World.from_file("small", seed=1, disturbances="small-disturbances")   # or a path, a dict, a spec
    world.person_contacts(), world.object_contacts(), world.contact_events()

People and boxes are kinematic PyBullet bodies (mass 0, placed every step in the world's pybullet thread):
sonar/laser rays and camera renders see them (the render processes mirror them), a robot's collision check
stops against them; a person waits while a robot stands within YIELD_M ahead (`yields: false`: walks on). Contacts are counted with getClosestPoints, not
getContactPoints: the world never runs stepSimulation, and Bullet reports no contacts between two mass-0
bodies anyway."""
from __future__ import annotations

import bisect
import logging
import math
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, NamedTuple, Protocol

import numpy as np
from .pybullet_quiet import p
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .body import Surroundings
from .errors import InvalidArgument
from .frames import yaw_quat
from .scenario_file import read_section

if TYPE_CHECKING:
    from collections.abc import Mapping

    from .body import Body
    from .floorplan import Plan

log = logging.getLogger(__name__)
GRAVITY = 9.81
YIELD_M = 0.25  # a person stops this far (beyond both bodies) from a robot ahead of them
TOUCH_M = 0.01  # closest distance that counts as touching: a blocked robot stops up to one step (~4 mm) short
PARKED = (0.0, 0.0, -60.0)  # where an absent body waits: below the floor, out of every ray and view
PERSON_COLOR = (0.22, 0.33, 0.55)
SKIN_COLOR = (0.85, 0.68, 0.55)
BOX_COLOR = (0.8, 0.45, 0.15)


class DisturbanceError(InvalidArgument):
    """A disturbance spec or file that cannot be used (the message says which entry and why)."""


# ------------------------------------------------------------------------------------------- the spec
def _range(minimum: float, strict: bool):
    """A number, or [lo, hi] drawn per seed; both ends at least (strict: above) `minimum`."""

    def check(v):
        lo, hi = (v, v) if isinstance(v, (int, float)) else v
        if lo > hi:
            raise ValueError(f"range [{lo}, {hi}]: the low end is above the high end")
        if lo < minimum or (strict and lo <= minimum):
            raise ValueError(f"must be {'>' if strict else '>='} {minimum:g}, got {lo:g}")
        return v

    return AfterValidator(check)


Seconds = Annotated[float | tuple[float, float], _range(0.0, strict=False)]
Speed = Annotated[float | tuple[float, float], _range(0.0, strict=True)]
Color = tuple[Annotated[float, Field(ge=0, le=1)], Annotated[float, Field(ge=0, le=1)],
              Annotated[float, Field(ge=0, le=1)]]


class Waypoint(BaseModel):
    """[x, y], [x, y, pause] or {x, y, pause}: pause = seconds standing still there."""

    model_config = ConfigDict(extra="forbid")
    x: float
    y: float
    pause: float = Field(default=0.0, ge=0.0)

    @model_validator(mode="before")
    @classmethod
    def _from_list(cls, v: Any) -> Any:
        if isinstance(v, (list, tuple)):
            if len(v) not in (2, 3):
                raise ValueError(f"a waypoint is [x, y] or [x, y, pause], got {list(v)}")
            return dict(zip(("x", "y", "pause"), v))
        return v


class PersonSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["person"]
    id: str = Field(min_length=1)
    route: list[Waypoint] = Field(min_length=1, description="one waypoint: the person stands there")
    speed: Speed = Field(default=1.0, description="m/s; at most 3 (running)")
    start: Seconds = 0.0
    loop: bool = False
    yields: bool = Field(default=True, description="waits while a robot stands in the way (people do not walk into robots)")
    width: float = Field(default=0.35, gt=0.1, le=1.0)
    height: float = Field(default=1.7, gt=0.3, le=2.5)
    color: Color = PERSON_COLOR
    face: str | None = Field(default=None, description="an image file (PNG/JPEG) of the person's face, worn on "
                                                        "the front of their head (face recognition)")

    @field_validator("face")
    @classmethod
    def _face_file(cls, v: str | None) -> str | None:
        if v is not None and not Path(v).is_file():
            raise ValueError(f"no face image {v!r}")
        return None if v is None else str(Path(v).resolve())

    @model_validator(mode="after")
    def _walkable(self) -> PersonSpec:
        if max(self.speed if isinstance(self.speed, tuple) else (self.speed,)) > 3.0:
            raise ValueError(f"speed {self.speed} m/s: a person walks at most 3 m/s")
        return self


class DoorSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["door"]
    id: str | None = Field(default=None, min_length=1, description="default: door-<door>-<index>")
    door: str = Field(min_length=1, description="a door id of the house")
    at: Seconds
    angle: float = Field(ge=0.0, le=180.0, description="target angle, degrees (0 closed, 90 open)")
    duration: float = Field(default=1.0, ge=0.0, description="seconds of the swing (0: at once)")


class BoxSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["box"]
    id: str = Field(min_length=1)
    at: Seconds
    position: tuple[float, float]
    size: tuple[Annotated[float, Field(gt=0, le=3)], Annotated[float, Field(gt=0, le=3)],
                Annotated[float, Field(gt=0, le=3)]]
    yaw: float = Field(default=0.0, description="degrees")
    drop_height: float = Field(default=0.0, ge=0.0, le=3.0, description="m from the floor to its bottom")
    color: Color = BOX_COLOR


class TouchSpec(BaseModel):
    """A person touching a robot's touch sensor (a NAO's head or hand) at `at`, for `seconds`."""
    model_config = ConfigDict(extra="forbid")
    kind: Literal["touch"]
    id: str | None = Field(default=None, min_length=1, description="default: touch-<robot>-<sensor>-<index>")
    robot: str = Field(min_length=1, description="the robot's name in the world (its type, unless named)")
    sensor: str = Field(min_length=1, description="one of its body's touch sensors (head_front, hand_left, ...)")
    at: Seconds
    seconds: float = Field(default=0.3, gt=0.0, le=60.0)

    @field_validator("sensor")
    @classmethod
    def _a_touch_sensor(cls, v: str) -> str:
        from .bodies import ROBOT_SPECS

        known = sorted({t for spec in ROBOT_SPECS.values() for t in spec.touch_sensors})
        if v not in known:
            raise ValueError(f"no robot body has a touch sensor {v!r} (known: {', '.join(known) or 'none'})")
        return v


Disturbance = Annotated[PersonSpec | DoorSpec | BoxSpec | TouchSpec, Field(discriminator="kind")]


class DisturbanceSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    disturbances: list[Disturbance] = Field(default_factory=list)

    @model_validator(mode="after")
    def _unique_ids(self) -> DisturbanceSpec:
        seen: set[str] = set()
        for i, d in enumerate(self.disturbances):
            if d.id is None:
                d.id = f"door-{d.door}-{i}" if d.kind == "door" else f"touch-{d.robot}-{d.sensor}-{i}"
            if d.id in seen:
                raise ValueError(f"two disturbances have the id {d.id!r}")
            seen.add(d.id)
        return self


def _loc(loc: tuple) -> str:
    """('disturbances', 0, 'person', 'speed') -> 'disturbances[0].speed' (the tag says nothing new)."""
    out = ""
    for i, x in enumerate(loc):
        if isinstance(x, int):
            out += f"[{x}]"
        elif not (i > 0 and isinstance(loc[i - 1], int) and x in ("person", "door", "box", "touch")):
            out += f".{x}" if out else str(x)
    return out


def _explain(exc: ValidationError, where: str) -> str:
    msgs = []
    for e in exc.errors()[:3]:
        loc = _loc(e["loc"])
        msgs.append(f"{loc}: {e['msg']}" if loc else e["msg"])
    more = f" (and {exc.error_count() - 3} more)" if exc.error_count() > 3 else ""
    return f"{where}: " + "; ".join(msgs) + more


def load_disturbances(source: str | Path | dict | list | DisturbanceSpec, search: Path | None = None
                      ) -> DisturbanceSpec:
    """A spec from a scenario file (its `disturbances:` list; a bare name is looked up as
    `search`/NAME.yaml), a mapping like the file's, a bare list of entries, or a spec."""
    if isinstance(source, DisturbanceSpec):
        return source
    where = "disturbance spec"
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.exists() and search is not None and (search / f"{path}.yaml").exists():
            path = search / f"{path}.yaml"
        where = f"disturbance file {path}"
        source = {"disturbances": read_section(path, "disturbances", DisturbanceError, "disturbance file")}
    if isinstance(source, list):
        source = {"disturbances": source}
    try:
        return DisturbanceSpec.model_validate(source)
    except ValidationError as exc:
        raise DisturbanceError(_explain(exc, where)) from None


# ---------------------------------------------------------------------------------------- timelines
def _draw(v, rng: np.random.Generator) -> float:
    return float(v) if isinstance(v, (int, float)) else float(rng.uniform(v[0], v[1]))


class Route:
    """A walk in time: stand at the first point until `start`, then legs (walks and pauses) at `speed`;
    `loop` closes the route and repeats it. Pure geometry (any thread)."""

    def __init__(self, points: list[tuple[float, float, float]], speed: float, start: float, loop: bool):
        self.start, self.loop = start, loop
        pts = list(points) + ([points[0]] if loop and len(points) > 1 else [])
        self.legs: list[tuple[float, float, tuple[float, float], tuple[float, float], float]] = []
        t, heading = 0.0, None
        for i, (x, y, pause) in enumerate(pts):
            if i > 0:
                px, py = pts[i - 1][:2]
                d = math.hypot(x - px, y - py)
                if d > 0:
                    heading = math.atan2(y - py, x - px)
                    self.legs.append((t, t + d / speed, (px, py), (x, y), heading))
                    t += d / speed
            last = loop and len(points) > 1 and i == len(pts) - 1  # back at the start: its pause comes next round
            if pause > 0 and not last:
                self.legs.append((t, t + pause, (x, y), (x, y), heading))
                t += pause
        self.period = t
        first = next((leg[4] for leg in self.legs if leg[4] is not None), 0.0)
        self.legs = [(t0, t1, a, b, first if h is None else h) for t0, t1, a, b, h in self.legs]
        self._starts = [leg[0] for leg in self.legs]
        self.home = (points[0][0], points[0][1], first)
        self.end = (points[-1][0], points[-1][1], self.legs[-1][4] if self.legs else first)

    def at(self, t: float) -> tuple[float, float, float]:
        """(x, y, heading) at simulation time t."""
        tau = t - self.start
        if tau <= 0 or not self.legs:
            return self.home
        if self.loop and self.period > 0:
            tau %= self.period
        elif tau >= self.period:
            return self.end
        t0, t1, a, b, heading = self.legs[max(bisect.bisect_right(self._starts, tau) - 1, 0)]
        f = min(max((tau - t0) / (t1 - t0), 0.0), 1.0) if t1 > t0 else 1.0
        return a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, heading


class BodyShape(NamedTuple):
    """What a mover looks like; also sent to the render processes to mirror it (both build it with
    create_body, so a frame from either shows the same body)."""

    kind: str  # "person" | "box"
    size: tuple[float, float, float]  # person: (width, width, height); box: (sx, sy, sz)
    color: tuple[float, float, float]  # person: the shirt
    face: str = ""  # person: an image file shown on a plate in front of the head ("": none)


TROUSERS_COLOR = (0.12, 0.13, 0.17)  # darker than the default shirt: the legs stand out from the torso
STRIDE_RAD, STANCE_RAD = 0.25, 0.06  # legs apart fore and aft (seen from the side) and sideways (from the front)


def _limb(top: tuple[float, float, float], roll: float, pitch: float, length: float, radius: float,
          color) -> tuple[tuple, tuple[float, float, float]]:
    """A cylinder hanging from `top`, turned by roll (about x) then pitch (about y); and its lower end."""
    q = p.getQuaternionFromEuler([roll, pitch, 0.0])
    down = np.asarray(p.getMatrixFromQuaternion(q)).reshape(3, 3) @ (0.0, 0.0, -1.0)
    centre, end = np.asarray(top) + down * length / 2, np.asarray(top) + down * length
    return (p.GEOM_CYLINDER, (radius, length), tuple(centre), q, color), tuple(end)


def person_parts(width: float, height: float, shirt) -> list[tuple]:
    """The visual parts of a person, (shape, dims, position, orientation, colour) in the body frame
    (origin at the centre, x the walking direction): legs in mid-stride, a torso, arms swinging the
    other way, a neck and a head, in an adult's proportions of `height`, as wide as `width`."""
    w, h, z0 = width, height, -height / 2
    hip, shoulder, head_r = 0.50 * h, 0.81 * h, 0.065 * h
    head = h - head_r  # the head's centre: the top of the head at `height`
    torso_w, torso_d = 0.78 * w, 0.55 * w
    leg_r, arm_r, arm_len = 0.2 * w, 0.12 * w, 0.36 * h
    t0 = hip - 0.05 * h
    parts = [(p.GEOM_BOX, (torso_d / 2, torso_w / 2, (shoulder - t0) / 2), (0.0, 0.0, z0 + (shoulder + t0) / 2),
              (0.0, 0.0, 0.0, 1.0), shirt),
             (p.GEOM_CYLINDER, (0.13 * w, head - shoulder), (0.0, 0.0, z0 + (shoulder + head) / 2),
              (0.0, 0.0, 0.0, 1.0), SKIN_COLOR),
             (p.GEOM_SPHERE, (head_r,), (0.0, 0.0, z0 + head), (0.0, 0.0, 0.0, 1.0), SKIN_COLOR)]
    for side in (-1, 1):  # a leg from the hip to the floor: feet apart sideways, one ahead, one behind
        roll, pitch = -side * STANCE_RAD, side * STRIDE_RAD
        parts.append(_limb((0.0, side * (torso_w / 2 - leg_r), z0 + hip), roll, pitch,
                           hip / (math.cos(roll) * math.cos(pitch)), leg_r, TROUSERS_COLOR)[0])
    for side in (-1, 1):  # an arm in the shirt's sleeve, swinging against its leg, and a hand
        roll, pitch = -side * STANCE_RAD, -side * STRIDE_RAD
        arm, wrist = _limb((0.0, side * (torso_w / 2 + arm_r + 0.005), z0 + shoulder - arm_r), roll, pitch,
                           arm_len + arm_r / 2, arm_r, shirt)
        parts += [arm, (p.GEOM_SPHERE, (1.15 * arm_r,), wrist, (0.0, 0.0, 0.0, 1.0), SKIN_COLOR)]
    return parts


def create_body(cid: int, shape: BodyShape, collision: bool = True) -> int:
    """A mass-0 body of `shape`, parked below the floor (its origin is its centre). A person looks
    human (person_parts), so that a people detector finds them in camera images, but collides as a
    cylinder of their width and height (what the range sensors and the robots' collision checks see)."""
    sx, sy, sz = shape.size
    if shape.kind == "person":
        col = p.createCollisionShape(p.GEOM_CYLINDER, radius=sx / 2, height=sz, physicsClientId=cid) if collision else -1
        parts = person_parts(sx, sz, shape.color)
        face = _face_plate(sx, sz, shape.face) if shape.face else None
        meshes = [("", [1.0, 1.0, 1.0])] * len(parts) + ([face[:2]] if face else [])
        if face:
            parts = parts + [face[2]]
        vis = p.createVisualShapeArray(
            shapeTypes=[t for t, *_ in parts],
            radii=[0.0 if t in (p.GEOM_BOX, p.GEOM_MESH) else dims[0] for t, dims, *_ in parts],
            lengths=[dims[1] if t == p.GEOM_CYLINDER else 0.0 for t, dims, *_ in parts],
            halfExtents=[list(dims) if t == p.GEOM_BOX else [0.0, 0.0, 0.0] for t, dims, *_ in parts],
            fileNames=[m for m, _ in meshes], meshScales=[s for _, s in meshes],
            visualFramePositions=[list(pos) for _, _, pos, _, _ in parts],
            visualFrameOrientations=[list(q) for *_, q, _ in parts],
            rgbaColors=[[*color, 1] for *_, color in parts], physicsClientId=cid)
    else:
        half = [sx / 2, sy / 2, sz / 2]
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=cid) if collision else -1
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[*shape.color, 1], physicsClientId=cid)
    body = p.createMultiBody(0, col, vis, list(PARKED), physicsClientId=cid)
    if shape.kind == "person" and shape.face:
        texture = p.loadTexture(shape.face, physicsClientId=cid)
        p.changeVisualShape(body, -1, shapeIndex=len(parts) - 1, textureUniqueId=texture, physicsClientId=cid)
    return body


FACE_QUAD = Path(__file__).resolve().parent / "data" / "face_quad.obj"  # a unit square facing +x, UV 0..1


def _face_plate(width: float, height: float, image: str) -> tuple[str, list[float], tuple]:
    """(mesh file, scale, visual part) of a plate showing `image` in front of the head of person_parts:
    as high as the head and a little more, as wide as the image's proportions make it."""
    import cv2

    img = cv2.imread(image)
    if img is None:
        raise InvalidArgument(f"the face image {image} cannot be read")
    head_r = 0.065 * height
    side_z = 2.4 * head_r
    side_y = side_z * img.shape[1] / img.shape[0]
    centre = (head_r + 0.004, 0.0, -height / 2 + height - head_r)  # just in front of the head's sphere
    return str(FACE_QUAD), [1.0, side_y, side_z], (p.GEOM_MESH, (0.0, 0.0), centre, (0.0, 0.0, 0.0, 1.0),
                                                    (1.0, 1.0, 1.0))


class Mover:
    """A person or a box: where it is at time t (None: absent)."""

    kind: str
    shape: BodyShape
    radius: float  # of its footprint, for near-by tests
    uid: int = -1
    placed: tuple | None = None  # (position, orientation) last set

    def __init__(self, ident: str):
        self.id = ident

    def pose_at(self, t: float) -> tuple[float, float, float, float] | None:  # (x, y, z centre, yaw)
        raise NotImplementedError


class Person(Mover):
    kind = "person"

    def __init__(self, spec: PersonSpec, rng: np.random.Generator):
        super().__init__(spec.id)
        self.speed, self.start = _draw(spec.speed, rng), _draw(spec.start, rng)
        self.route = Route([(w.x, w.y, w.pause) for w in spec.route], self.speed, self.start, spec.loop)
        self.shape = BodyShape("person", (spec.width, spec.width, spec.height), tuple(spec.color), spec.face or "")
        self.radius = spec.width / 2
        self.yields = spec.yields
        self.delay = 0.0  # time spent waiting for robots to get out of the way (the route runs this late)
        self.last_t: float | None = None

    def pose_at(self, t):
        x, y, yaw = self.route.at(t - self.delay)
        return x, y, self.shape.size[2] / 2, yaw

    def robot_in_the_way(self, pose, robots) -> bool:
        """A robot within YIELD_M of this person's next position, ahead of them."""
        for rb in robots:
            dx, dy = rb.pose[0] - pose[0], rb.pose[1] - pose[1]
            d = math.hypot(dx, dy)
            if d < self.radius + rb.spec.radius + YIELD_M and \
                    (dx * math.cos(pose[3]) + dy * math.sin(pose[3])) > 0.3 * d:
                return True
        return False


class DroppedBox(Mover):
    kind = "box"

    def __init__(self, spec: BoxSpec, rng: np.random.Generator):
        super().__init__(spec.id)
        self.at = _draw(spec.at, rng)
        self.position, self.yaw, self.drop_height = spec.position, math.radians(spec.yaw), spec.drop_height
        self.shape = BodyShape("box", tuple(spec.size), tuple(spec.color))
        self.radius = math.hypot(spec.size[0], spec.size[1]) / 2

    def pose_at(self, t):
        if t < self.at:
            return None
        fall = max(self.drop_height - GRAVITY / 2 * (t - self.at) ** 2, 0.0)
        return self.position[0], self.position[1], self.shape.size[2] / 2 + fall, self.yaw


class DoorMotion:
    """Swing a door from its angle at `at` to `angle` over `duration` (linear in time)."""

    def __init__(self, spec: DoorSpec, rng: np.random.Generator):
        self.id, self.door, self.target, self.duration = spec.id, spec.door, spec.angle, spec.duration
        self.at = _draw(spec.at, rng)
        self.from_angle: float | None = None
        self.finished = False

    @property
    def end(self) -> float:
        return self.at + self.duration

    def angle_at(self, t: float, current: float) -> float | None:
        """The door's angle at t, or None while this motion does not drive it."""
        if self.finished or t < self.at:
            return None
        if self.from_angle is None:
            self.from_angle = current
        f = 1.0 if self.duration <= 0 else min((t - self.at) / self.duration, 1.0)
        self.finished = f >= 1.0
        return self.from_angle + (self.target - self.from_angle) * f


class TouchAt:
    """Press a robot's touch sensor at `at` (World.touch's effect, on the scenario's timeline)."""

    def __init__(self, spec: TouchSpec, rng: np.random.Generator):
        self.id, self.robot, self.sensor, self.seconds = spec.id, spec.robot, spec.sensor, spec.seconds
        self.at = _draw(spec.at, rng)
        self.done = False

    def press(self, world: Stage, t: float) -> None:
        """pybullet thread, inside a step: a touch its world cannot take is logged, never raised
        (the step would end every motion)."""
        self.done = True
        try:
            world.touch_in_thread(self.robot, self.sensor, self.seconds)
        except InvalidArgument as e:
            log.warning("touch %r at %.1f s not made: %s", self.id, t, e)


@dataclass(frozen=True)
class ContactEvent:
    """A robot started touching a person or box (one per touching episode)."""

    time: float
    robot: str
    other: str  # the disturbance id
    kind: str  # "person" | "box"


# ------------------------------------------------------------------------------------------ runtime
class Stage(Surroundings, Protocol):
    """The world the disturbances move things in (robots.world.World): what a body sees of it (its
    client, clock, house), its robots and its doors."""

    @property
    def robots(self) -> Mapping[str, Body]:
        """The robots a person waits for and a mover touches."""

    def set_door_in_thread(self, door_id: str, angle_deg: float) -> None:
        """Swing a door (pybullet thread)."""

    def touch_in_thread(self, robot: str, sensor: str, seconds: float) -> None:
        """Press a robot's touch sensor now for `seconds` (pybullet thread); InvalidArgument when it
        has none of that name."""


class Disturbances:
    """The disturbances of one world, resolved against its house and seed. Built and advanced in the
    world's pybullet thread (World.attach_disturbances, World._advance); reads are safe from any thread."""

    def __init__(self, spec: DisturbanceSpec, plan: Plan):
        self.spec = spec
        self.movers: list[Mover] = []
        self.doors: list[DoorMotion] = []
        self.touches: list[TouchAt] = []
        doors = {d.id: d for d in plan.doors}
        x0, y0, x1, y1 = plan.bounds
        for i, d in enumerate(spec.disturbances):
            where = f"disturbances[{i}] ({d.kind} {d.id!r})"
            rng = np.random.default_rng([plan.seed, zlib.crc32(f"disturbance/{d.id}".encode())])
            points = [(w.x, w.y) for w in d.route] if d.kind == "person" else \
                [d.position] if d.kind == "box" else []
            for x, y in points:
                if not (x0 <= x <= x1 and y0 <= y <= y1):
                    raise DisturbanceError(f"{where}: point ({x:g}, {y:g}) is outside house {plan.name!r} "
                                           f"(x {x0:g}..{x1:g}, y {y0:g}..{y1:g})")
            if d.kind == "person":
                self.movers.append(Person(d, rng))
            elif d.kind == "box":
                self.movers.append(DroppedBox(d, rng))
            elif d.kind == "touch":
                self.touches.append(TouchAt(d, rng))  # its robot and sensor: checked when it comes
            else:
                if d.door not in doors:
                    raise DisturbanceError(f"{where}: unknown door {d.door!r} in house {plan.name!r} "
                                           f"(doors: {', '.join(doors) or 'none'})")
                self.doors.append(DoorMotion(d, rng))
        by_door: dict[str, list[DoorMotion]] = {}
        for m in sorted(self.doors, key=lambda m: m.at):
            prev = by_door.setdefault(m.door, [])
            if prev and m.at < prev[-1].end:
                raise DisturbanceError(f"door {m.door}: {m.id!r} starts at {m.at:g} s, before {prev[-1].id!r} "
                                       f"ends at {prev[-1].end:g} s")
            prev.append(m)
        self.events: list[ContactEvent] = []
        self._touching: set[tuple[str, str]] = set()
        self.world: Stage | None = None

    # ---- pybullet thread
    def build(self, world: Stage) -> None:
        self.world = world
        for m in self.movers:
            m.uid = create_body(world.cid, m.shape)
        self.advance(world.clock.time)

    def advance(self, t: float) -> None:
        """Place every mover and door for time t, then count new contacts with robots."""
        world = self.world
        cid = world.cid
        robots = list(world.robots.values())
        for m in self.movers:
            pose = m.pose_at(t)
            if isinstance(m, Person) and m.yields:
                if pose is not None and m.last_t is not None and m.robot_in_the_way(pose, robots):
                    m.delay += t - m.last_t  # stays where it stood
                    pose = m.pose_at(t)
                m.last_t = t
            placed = (PARKED, (0.0, 0.0, 0.0, 1.0)) if pose is None else \
                ((pose[0], pose[1], pose[2]), tuple(yaw_quat(pose[3])))
            if placed != m.placed:
                p.resetBasePositionAndOrientation(m.uid, placed[0], placed[1], physicsClientId=cid)
                m.placed = placed
        for d in self.doors:
            if not d.finished and t >= d.at:
                world.set_door_in_thread(d.door, d.angle_at(t, next(x.angle for x in world.plan.doors if x.id == d.door)))
        for touch in self.touches:
            if not touch.done and t >= touch.at:
                touch.press(world, t)
        self._count_contacts(t, robots)

    def _count_contacts(self, t: float, robots: list[Body]) -> None:
        cid = self.world.cid
        for rb in robots:
            rx, ry = rb.pose[0], rb.pose[1]
            for m in self.movers:
                key = (rb.name, m.id)
                at = m.placed[0] if m.placed is not None else PARKED
                touching = at != PARKED and \
                    math.hypot(at[0] - rx, at[1] - ry) <= rb.spec.radius + m.radius + TOUCH_M + 0.01 and \
                    bool(p.getClosestPoints(rb.probe, m.uid, TOUCH_M, physicsClientId=cid))
                if touching and key not in self._touching:
                    self._touching.add(key)
                    self.events.append(ContactEvent(t, rb.name, m.id, m.kind))
                elif not touching:
                    self._touching.discard(key)

    def bodies_near(self, x: float, y: float, r: float) -> list[int]:
        """Uids of present movers whose footprint may be within r of (x, y) (robot collision checks)."""
        out = []
        for m in self.movers:
            if m.placed is not None and m.placed[0] != PARKED:
                px, py = m.placed[0][:2]
                if math.hypot(px - x, py - y) < r + m.radius + 0.1:
                    out.append(m.uid)
        return out

    def scene_bodies(self) -> dict[str, tuple[BodyShape, tuple, tuple]]:
        """id -> (shape, position, orientation) of every mover (absent ones parked): the render mirror's."""
        return {m.id: (m.shape, *m.placed) for m in self.movers if m.placed is not None}

    # ---- any thread
    def poses(self) -> dict[str, tuple[float, float, float]]:
        """Present movers: id -> (x, y, yaw) (ground truth)."""
        out = {}
        for m in self.movers:
            placed = m.placed
            if placed is not None and placed[0] != PARKED:
                (x, y, _), q = placed
                out[m.id] = (x, y, 2 * math.atan2(q[2], q[3]))
        return out

    def contacts(self, kind: str, robot: str | None = None) -> int:
        return sum(1 for e in list(self.events) if e.kind == kind and (robot is None or e.robot == robot))
