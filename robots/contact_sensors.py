"""Contact sensors: a NAO's foot bumpers (raised by real contacts in the PyBullet world) and its head and
hand touch sensors (pressed by a scenario or a test: World.touch, a simulated person's hand).

A bumper is the toe of a foot (its front TOE_M, the foot's width, FOOT_H_M high). The walk is abstracted
(the base slides; the legs keep their posture), and the collision cylinder that stops the base stands for
the whole walking body, so a standing foot's toe never reaches what stopped the cylinder. While the base
is driven forward, the swing foot's toe reaches a step (NAO's MaxStepX, STRIDE_M) ahead of where the
standing foot is: the bumper's box is then the toe swept that far forward. A bumper is pressed while its box
is within TOUCH_M of a wall, door, furniture, lamp, robot, person or dropped box (Bullet's closest points
against the obstacle's collision shape), so it fires when the NAO walks into something at foot height,
not into a table top above its feet; a person walking into a standing NAO's feet presses it too.

Every step of the world (robots/world.py) checks the bumpers and ends touches whose time is over; each
press and release is kept, numbered, for RobotAPI.get_contacts `after`.
"""
from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from .errors import InvalidArgument
from .pybullet_quiet import p

if TYPE_CHECKING:
    from .body import Body

TOE_M, FOOT_W_M, FOOT_H_M = 0.02, 0.08, 0.03  # the toe strip of a NAO foot (robots/nao.py: 0.16 x 0.08 x 0.03)
FOOT_FRONT_M = 0.10  # the toe's front from the ankle, in the foot's frame (x forward)
FOOT_BOTTOM_M = -0.045  # the sole below the ankle
STRIDE_M = 0.08  # NAO's MaxStepX: how far ahead of the standing foot the swing foot lands
TOUCH_M = 0.005  # a box this near an obstacle touches it (the base stops up to one step short)
WALKING_MPS = 0.005  # the base's commanded forward speed above which the feet swing
KEEP = 100  # changes kept (ontology.robot.CONTACT_BUFFER)


class BumperSpec(NamedTuple):
    name: str  # "bumper_left"
    link: str  # the foot's link ("LFoot"), x forward at the ankle


class Change(NamedTuple):
    sensor: str
    kind: str  # "bumper" | "touch"
    pressed: bool
    stamp: float  # simulation time
    seq: int  # 1, 2, ... in the order they happened


class ContactSensors:
    """A robot's bumpers and touch sensors; methods run in the world's pybullet thread, `pressed` and
    `since` may be read from any thread."""

    def __init__(self, robot: "Body", bumpers: tuple[BumperSpec, ...], touch: tuple[str, ...]):
        self.robot, self.bumpers, self.touch_names = robot, bumpers, touch
        self.pressed: dict[str, bool] = {b.name: False for b in bumpers} | {t: False for t in touch}
        self.changes: deque[Change] = deque(maxlen=KEEP)
        self.last = 0  # the newest change's seq
        self._touch_until: dict[str, float] = {}
        self._drives = robot.base.steps  # the base's steps when last checked: driven since?
        cid = robot.world.cid
        self._shapes = {depth: p.createCollisionShape(p.GEOM_BOX, halfExtents=[depth / 2, FOOT_W_M / 2, FOOT_H_M / 2],
                                                      physicsClientId=cid) for depth in (TOE_M, TOE_M + STRIDE_M)}

    def kind(self, sensor: str) -> str:
        return "touch" if sensor in self.touch_names else "bumper"

    def _set(self, sensor: str, pressed: bool, t: float) -> None:
        if self.pressed[sensor] != pressed:
            self.pressed[sensor] = pressed
            self.changes.append(Change(sensor, self.kind(sensor), pressed, t, self.last + 1))
            self.last += 1

    def after(self, seq: int | None) -> list[Change]:
        """The changes after the one numbered `seq` (None: none), oldest first."""
        return [] if seq is None else [c for c in list(self.changes) if c.seq > seq]

    # ---- pybullet thread
    def touch(self, sensor: str, t: float, seconds: float) -> None:
        """Press a touch sensor at simulation time `t` for `seconds` of simulation time."""
        if sensor not in self.touch_names:
            raise InvalidArgument(f"{self.robot.name} has no touch sensor {sensor!r} "
                                  f"(known: {', '.join(self.touch_names) or 'none'})")
        if not seconds > 0:
            raise InvalidArgument(f"a touch lasts a positive time, not {seconds!r} s")
        self._set(sensor, True, t)
        self._touch_until[sensor] = t + seconds

    def step(self, t: float) -> None:
        """After a world step at simulation time `t`: bumpers against obstacles, touches that end."""
        for sensor, until in list(self._touch_until.items()):
            if t >= until - 1e-9:
                del self._touch_until[sensor]
                self._set(sensor, False, t)
        if not self.bumpers:
            return
        base = self.robot.base
        walking = base.steps != self._drives and base.command[0] > WALKING_MPS
        self._drives = base.steps
        r = self.robot
        near = r.world.obstacles_near(r.pose[0], r.pose[1], r.spec.radius + STRIDE_M + 0.05, exclude=r.probe)
        for b in self.bumpers:
            self._set(b.name, bool(near) and self._touching(b, near, walking), t)

    def _touching(self, b: BumperSpec, near: list[int], walking: bool) -> bool:
        depth = TOE_M + (STRIDE_M if walking else 0.0)
        T = self.robot.link_pose(b.link)
        centre = T[:3, :3] @ np.array([FOOT_FRONT_M - TOE_M + depth / 2, 0.0, FOOT_BOTTOM_M + FOOT_H_M / 2]) + T[:3, 3]
        orn = _quat(T[:3, :3])
        cid = self.robot.world.cid
        return any(p.getClosestPoints(bodyA=-1, bodyB=uid, distance=TOUCH_M, collisionShapeA=self._shapes[depth],
                                      collisionShapePositionA=centre.tolist(), collisionShapeOrientationA=orn,
                                      physicsClientId=cid) for uid in near)


def _quat(R: np.ndarray) -> list[float]:
    """Quaternion (x, y, z, w) of a rotation matrix."""
    w = np.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2, R[2, 1] - R[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2, R[0, 2] - R[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2, R[1, 0] - R[0, 1])
    return [float(x), float(y), float(z), float(w)]
