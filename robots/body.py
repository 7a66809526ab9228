"""What a robot's parts need of the robot they belong to, as typed Protocols. The effectors, receptors,
motion controllers, failure modes and contact sensors type against `Body`, not against
robots.robot.Robot: Robot builds them, so importing it back would make a loop. robots.robot.Robot
implements Body and robots.world.World implements Surroundings. Everything here runs in the world's
pybullet thread unless it says otherwise."""
from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:  # for annotations only: importing this module costs nothing
    from collections.abc import Mapping
    from contextlib import AbstractContextManager

    import numpy as np

    from .floorplan import Plan
    from .odometry import Odometry
    from .simclock import SimClock
    from .spec import RobotSpec


class Surroundings(Protocol):
    """What a body needs of the world it stands in."""

    @property
    def cid(self) -> int:
        """The world's PyBullet client."""

    @property
    def clock(self) -> SimClock:
        """Simulation time (`time`) and its fixed step (`step`): sensor noise is seeded by the step."""

    @property
    def plan(self) -> Plan:
        """The house as built: its `seed` seeds the robots' noise, `slip_at` gives the floor's slip."""

    @property
    def emissive(self) -> dict[int, tuple[float, float, float]]:
        """Body uid -> radiance (1 = a lit white wall): lit lamp shades and windows by day, what a
        camera renders as light sources (robots/lighting.py)."""

    @property
    def light_scale(self) -> float:
        """The room's ambient and diffuse light beyond what the sky gives it (1: as the house is lit)."""

    def obstacles_near(self, x: float, y: float, r: float, exclude: int = -1) -> list[int]:
        """Uids of what may stand within `r` of (x, y) (walls, doors, furniture, lamps, robots' probes,
        people, dropped boxes), `exclude` left out."""


class Motion(Protocol):
    """A motion under way (a robots.controllers.Controller), as Body.controllers holds it."""

    done: bool
    cancelled: bool


class MovingJoints(Motion, Protocol):
    """Joints on their way to targets at a constant speed (robots.controllers.JointMotion)."""

    targets: dict[str, float] | None
    speed: float  # rad/s


class Base(Protocol):
    """The mobile base (robots.effectors.BaseEffector)."""

    command: tuple[float, float, float]  # the velocity of the last step driven, robot frame
    steps: int  # steps driven so far

    def check_velocity(self, vx: float, vy: float, wz: float) -> tuple[float, float, float]:
        """The velocity clipped to the body's limits; UnsupportedOperation for a sideways one on a
        differential drive."""

    def drive(self, vx: float, vy: float, wz: float, dt: float) -> bool:
        """One exact step of the true pose; True when an obstacle blocked the translation."""


class Head(Protocol):
    """The head's look-at solver (robots.effectors.HeadEffector)."""

    def solve(self, target: tuple[float, float, float]) -> dict[str, float]:
        """Head joint angles that put a point of the house on the look camera's axis."""


class Gait(Protocol):
    """How the base moves with a real robot's errors (robots.failure_modes.Locomotion)."""

    def drive(self, robot: Body, vx: float, vy: float, wz: float, dt: float) -> bool:
        """One step of the base with slip and sway; True when an obstacle blocked it."""

    def settle(self, robot: Body) -> None:
        """The motion ended: the body comes to rest over its feet."""

    def sway_speed(self) -> float:
        """The body's sideways speed from its sway now (m/s), for motion blur."""

    def tilt(self) -> tuple[float, float]:
        """The torso's roll toward the stance foot (rad, + = left) and its height off the standing one (m)."""

    def tilt_rates(self) -> tuple[float, float]:
        """How fast the roll (rad/s) and the height (m/s) change now, for motion blur."""

    def finishing(self) -> bool:
        """A stopped walk's step is still under way (the world steps it to its end)."""

    def tick(self, robot: Body, dt: float) -> None:
        """After each world step: a stopped walk's step goes on to its end."""


class Body(Protocol):
    """A robot in a world, as its parts see it."""

    @property
    def name(self) -> str:
        """The robot's name in its world (seeds its noise)."""

    @property
    def spec(self) -> RobotSpec:
        """Its body's description: limits, sensors, postures."""

    @property
    def world(self) -> Surroundings:
        """The world it stands in."""

    @property
    def pose(self) -> tuple[float, float, float]:
        """The true base pose (x, y, heading); set_base_pose changes it."""

    @property
    def q(self) -> dict[str, float]:
        """Joint angles now (rad); set_joint changes them."""

    @property
    def limits(self) -> dict[str, tuple[float, float]]:
        """Each joint's (low, high) angle."""

    @property
    def root_link(self) -> str:
        """The base link's name."""

    @property
    def joint_parent(self) -> dict[str, str]:
        """Joint -> the link it hangs from."""

    @property
    def probe(self) -> int:
        """Uid of its collision-probe cylinder."""

    @property
    def protection_m(self) -> float | None:
        """The collision protection's margin (robots.interface.RobotInterface.protect), None: off."""

    @property
    def odometry(self) -> Odometry:
        """What the robot believes it moved: `estimate`, `update`."""

    @property
    def base(self) -> Base:
        """Its mobile base."""

    @property
    def head(self) -> Head:
        """Its head's look-at solver."""

    @property
    def locomotion(self) -> Gait | None:
        """Its motion errors, None: an ideal robot."""

    @property
    def controllers(self) -> Mapping[str, Motion]:
        """The motions under way, by slot ("base", "joints:..."); changed in the event loop's thread."""

    def set_base_pose(self, x: float, y: float, th: float) -> None:
        """Place the body and its probe at the true pose (x, y, th)."""

    def collides(self, x: float, y: float) -> bool:
        """Would the collision cylinder at (x, y) penetrate anything?"""

    def probe_hidden(self) -> AbstractContextManager[None]:
        """The own collision cylinder moved away meanwhile (so the robot's own rays miss it)."""

    def set_joint(self, name: str, angle: float) -> None:
        """Set one joint's angle (rad)."""

    def update_lift(self) -> None:
        """Keep the feet on the floor after the joints moved (a NAO's virtual lift joint)."""

    def front_margin(self) -> float | None:
        """How close the nearest range reading ahead is beyond its sensor's minimum range; None
        without range sensors."""

    def link_pose(self, link: str) -> np.ndarray:
        """4x4 world pose of a link, as the robot's kinematics give it (no torso roll or bob)."""

    def body_sway(self) -> np.ndarray | None:
        """The world transform of the torso's roll and bob now (a NAO walking by steps), None: upright."""

    def tilt_pivot_z(self) -> float:
        """Height of the torso's roll axis, m."""

    def joint_offset(self, joint: str) -> np.ndarray:
        """Fixed transform parent link frame -> joint frame (at joint angle 0)."""

    def joint_offset_of_link(self, link: str) -> np.ndarray:
        """joint_offset of the joint that moves `link`."""
