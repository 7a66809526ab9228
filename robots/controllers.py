"""Motion controllers stepped by the World in simulation time (all run in the pybullet thread).

A controller's ``step(dt)`` advances it by one fixed step and returns True when finished; raising a
RobotError fails the awaiting call. ``blocking`` controllers (motions someone awaits, timers) keep an
unpaced (rtf=0) world stepping; background ones (move_vel) only advance while something else does or
when the world is paced (rtf>0)."""
from __future__ import annotations

import asyncio
import math
from typing import TYPE_CHECKING, Any


from .errors import MotionBlocked, RobotError
from .odometry import wrap

if TYPE_CHECKING:
    from .body import Body

POS_TOL, ANG_TOL = 0.003, 0.002
BLOCKED_AFTER = 0.5  # s of blocked translation before a motion fails
PROTECT_EVERY_S = 0.05  # the collision protection reads the range sensors this often (simulated time)


class Controller:
    blocking = True
    slot = ""

    def __init__(self):
        self.done = False
        self.cancelled = False
        self.result: Any = None
        self.error: BaseException | None = None
        self.future: asyncio.Future | None = None

    def step(self, dt: float) -> bool:  # pragma: no cover - abstract
        raise NotImplementedError

    def resolve(self) -> None:
        f = self.future
        if f is None or f.done():
            return
        if self.error is not None:
            f.set_exception(self.error)
        else:
            f.set_result(self.result)

    def cancel(self, error: RobotError) -> None:
        """Loop thread: stop stepping this controller and fail its awaiting call with `error`."""
        self.cancelled = True
        if self.future is not None and not self.future.done():
            self.future.set_exception(error)
            self.future.exception()  # mark retrieved: nobody may await a pre-empted background motion


class Timer(Controller):
    def __init__(self, duration: float):
        super().__init__()
        self.remaining = duration

    def step(self, dt: float) -> bool:
        self.remaining -= dt
        return self.remaining <= 1e-9


class Observer(Timer):
    """A timer that does not drive an unpaced world: it waits for time others make pass (samplers,
    scripts) instead of running the simulation ahead of what the agents are doing."""
    blocking = False


# ----------------------------------------------------------------------------- base motions
class BaseController(Controller):
    slot = "base"

    def __init__(self, robot: "Body"):
        super().__init__()
        self.robot = robot
        self.blocked_time = 0.0
        self.start_pose = robot.pose
        self.unchecked_s = PROTECT_EVERY_S  # check at the first forward step

    def drive(self, vx: float, vy: float, wz: float, dt: float) -> None:
        vx, vy, wz = self.robot.base.check_velocity(vx, vy, wz)
        self.protect(vx, dt)
        if drive_base(self.robot, vx, vy, wz, dt):
            self.blocked_time += dt
            if self.blocked_time >= BLOCKED_AFTER:
                moved = math.hypot(self.robot.pose[0] - self.start_pose[0], self.robot.pose[1] - self.start_pose[1])
                raise MotionBlocked(f"{self.robot.name}: an obstacle blocked the base after {moved:.2f} m")
        else:
            self.blocked_time = 0.0

    def protect(self, vx: float, dt: float) -> None:
        """The robot's collision protection (RobotAPI.protect): stop before driving into what the
        range sensors see ahead."""
        margin_m = self.robot.protection_m
        if margin_m is None or vx <= 0.02:
            return
        self.unchecked_s += dt
        if self.unchecked_s < PROTECT_EVERY_S:
            return
        self.unchecked_s = 0.0
        seen = self.robot.front_margin()
        if seen is not None and seen < margin_m:
            raise MotionBlocked(f"{self.robot.name}: its collision protection stopped it: something "
                                f"{seen:.2f} m beyond the range sensors' minimum, ahead")

    def settle(self) -> None:
        """The motion is done: a swaying body comes to rest over its feet."""
        if self.robot.locomotion is not None:
            self.robot.locomotion.settle(self.robot)


def drive_base(robot: "Body", vx: float, vy: float, wz: float, dt: float) -> bool:
    """One step of the base: exact (ideal robot) or with the robot's slip and sway (robots/failure_modes.py);
    True when an obstacle blocked the translation."""
    robot.base.steps += 1
    if robot.locomotion is None:
        return robot.base.drive(vx, vy, wz, dt)
    return robot.locomotion.drive(robot, vx, vy, wz, dt)


class VelocityController(BaseController):
    blocking = False

    def __init__(self, robot: "Body", vx: float, vy: float, wz: float):
        super().__init__(robot)
        self.v = robot.base.check_velocity(vx, vy, wz)

    def step(self, dt: float) -> bool:
        drive_base(self.robot, *self.v, dt)  # pushes against obstacles without failing
        return False


def _to_robot(pose, gx: float, gy: float) -> tuple[float, float]:
    x, y, th = pose
    dx, dy = gx - x, gy - y
    return math.cos(th) * dx + math.sin(th) * dy, -math.sin(th) * dx + math.cos(th) * dy


def _sat(v: float, limit: float, floor: float = 0.0) -> float:
    a = min(abs(v) * 1.0, limit)
    a = max(a, min(floor, abs(v))) if floor else a
    return math.copysign(a, v)


class GoToPose(BaseController):
    """Reach a global goal pose (in the estimate frame). Holonomic: straight P control of x, y, theta.
    Differential drive: turn towards the goal, drive, turn to the goal heading."""

    def __init__(self, robot: "Body", goal: tuple[float, float, float] | None = None,
                 relative: tuple[float, float, float] | None = None):
        super().__init__(robot)
        self.goal, self.relative = goal, relative
        self.phase = "turn"

    def _resolve_goal(self) -> None:
        if self.goal is None:
            x, y, th = self.robot.odometry.estimate
            rx, ry, rth = self.relative
            self.goal = (x + math.cos(th) * rx - math.sin(th) * ry, y + math.sin(th) * rx + math.cos(th) * ry,
                         wrap(th + rth))

    def step(self, dt: float) -> bool:
        self._resolve_goal()
        s = self.robot.spec
        est = self.robot.odometry.estimate
        ex, ey = _to_robot(est, self.goal[0], self.goal[1])
        eth = wrap(self.goal[2] - est[2])
        dist = math.hypot(ex, ey)
        if s.holonomic:
            if dist < POS_TOL and abs(eth) < ANG_TOL:
                self.settle()
                return True
            k = 2.0
            vx, vy, wz = k * ex, k * ey, k * eth
            speed = math.hypot(vx, vy)
            if 0 < speed < 0.02 and dist >= POS_TOL:
                vx, vy = vx * 0.02 / speed, vy * 0.02 / speed
            if abs(wz) < 0.05 and abs(eth) >= ANG_TOL:
                wz = math.copysign(0.05, eth)
            scale = max(abs(vx) / s.max_vx, abs(vy) / s.max_vy, abs(wz) / s.max_wz, 1.0)
            self.drive(vx / scale, vy / scale, wz / scale, dt)
            return False
        # differential drive
        if self.phase == "turn":
            if dist < 0.01:
                self.phase = "align"
            else:
                err = math.atan2(ey, ex)
                if abs(err) < ANG_TOL:
                    self.phase = "drive"
                else:
                    self.drive(0.0, 0.0, _sat(3 * err, s.max_wz, 0.05), dt)
                    return False
        if self.phase == "drive":
            if ex < POS_TOL:
                self.phase = "align"
            else:
                bearing = math.atan2(ey, ex) if dist > 0.05 else 0.0
                self.drive(_sat(2 * ex, s.max_vx, 0.02), 0.0, _sat(2 * bearing, s.max_wz), dt)
                return False
        if abs(eth) < ANG_TOL:
            self.settle()
            return True
        self.drive(0.0, 0.0, _sat(3 * eth, s.max_wz, 0.05), dt)
        return False


SHARP_TURN = 0.3  # rad: the carrot stops at path corners turning more than this
CORNER_REACHED = 0.03  # m: a corner this near counts as passed
ALIGNED = 0.3  # rad: a holonomic robot starts walking a path once its heading is this close
TURN_IN_PLACE = 0.3  # rad: a differential drive turns on the spot while its carrot is further off its heading


class PathFollower(BaseController):
    """Follow a global path using the ESTIMATED pose: pure pursuit (diff drive) or a holonomic
    carrot P controller (NAO); the final pose (with heading) is reached with GoToPose."""

    LOOKAHEAD = 0.35

    def __init__(self, robot: "Body", poses: list[tuple[float, float, float]]):
        super().__init__(robot)
        pts: list[tuple[float, float]] = []
        for q in poses:
            if not pts or math.hypot(q[0] - pts[-1][0], q[1] - pts[-1][1]) > 1e-3:
                pts.append((float(q[0]), float(q[1])))
        # plain floats: the follower runs every world step, and numpy on 2-vectors costs ~5x more
        self.pts = pts
        self.lengths = [math.dist(a, b) for a, b in zip(pts, pts[1:])]
        self._after = [sum(self.lengths[i + 1:]) for i in range(len(self.lengths))]  # path length past segment i
        self.final = tuple(map(float, poses[-1]))
        self.seg = 0
        self.finisher: GoToPose | None = None
        self.aligning = True  # holonomic: turn towards the path before walking

    def _project(self, i: int, x: float, y: float) -> tuple[float, float]:
        (ax, ay), (bx, by) = self.pts[i], self.pts[i + 1]
        abx, aby = bx - ax, by - ay
        t = min(max(((x - ax) * abx + (y - ay) * aby) / max(abx * abx + aby * aby, 1e-12), 0.0), 1.0)
        return t, math.hypot(ax + t * abx - x, ay + t * aby - y)

    def _turn(self, i: int) -> float:
        """Heading change (rad) of the path at vertex i."""
        (px, py), (qx, qy), (rx, ry) = self.pts[i - 1], self.pts[i], self.pts[i + 1]
        ax, ay, bx, by = qx - px, qy - py, rx - qx, ry - qy
        return abs(math.atan2(ax * by - ay * bx, ax * bx + ay * by))

    def _carrot(self, x: float, y: float) -> tuple[tuple[float, float], float, float]:
        """Carrot point LOOKAHEAD ahead of the projection (never past a sharp corner: cutting it is
        how a robot hits a door frame), the remaining arc length and the distance to that corner."""
        nseg = len(self.lengths)
        while self.seg < nseg - 1 and math.dist(self.pts[self.seg + 1], (x, y)) < CORNER_REACHED:
            self.seg += 1
        best = min(range(self.seg, min(self.seg + 3, nseg)), key=lambda i: self._project(i, x, y)[1])
        self.seg = max(self.seg, best)
        t, _ = self._project(self.seg, x, y)
        remaining = (1 - t) * self.lengths[self.seg] + self._after[self.seg]
        (ax, ay), (bx, by) = self.pts[self.seg], self.pts[self.seg + 1]
        pt, left, i = (ax + t * (bx - ax), ay + t * (by - ay)), self.LOOKAHEAD, self.seg + 1
        ahead = 0.0
        while i < len(self.pts):
            nxt = self.pts[i]
            d = math.dist(nxt, pt)
            if d >= left:
                f = left / d
                return (pt[0] + (nxt[0] - pt[0]) * f, pt[1] + (nxt[1] - pt[1]) * f), remaining, math.inf
            left -= d
            ahead += d
            if i < len(self.pts) - 1 and self._turn(i) > SHARP_TURN:
                return nxt, remaining, ahead
            pt, i = nxt, i + 1
        return pt, remaining, math.inf

    def step(self, dt: float) -> bool:
        if self.finisher is None:
            s = self.robot.spec
            est = self.robot.odometry.estimate
            carrot, remaining, corner = (self._carrot(est[0], est[1]) if len(self.pts) > 1
                                         else (self.pts[-1], 0.0, math.inf))
            if remaining < 0.03:
                self.finisher = GoToPose(self.robot, goal=self.final)
                self.finisher.blocked_time = self.blocked_time
            else:
                cx, cy = _to_robot(est, carrot[0], carrot[1])
                ld = max(math.hypot(cx, cy), 1e-6)
                alpha = math.atan2(cy, cx)
                slow = min(1.0, max(remaining / 0.4, 0.15), max(corner / 0.3, 0.3))
                if s.holonomic:
                    v = s.max_vx * slow
                    vx, vy = v * cx / ld, v * cy / ld
                    heading = math.atan2(carrot[1] - est[1], carrot[0] - est[0]) if remaining > 0.3 else self.final[2]
                    err = wrap(heading - est[2])
                    wz = 1.5 * err
                    self.aligning = self.aligning and abs(err) > ALIGNED
                    if self.aligning:  # a large turn first, on the spot: walking while turning curves off the path
                        vx = vy = 0.0
                        wz = math.copysign(max(abs(wz), 0.3), wz)
                    scale = max(abs(vx) / s.max_vx, abs(vy) / s.max_vy, abs(wz) / s.max_wz, 1.0)
                    self.drive(vx / scale, vy / scale, wz / scale, dt)
                elif abs(alpha) > TURN_IN_PLACE:  # arcs started at larger angles overshoot the path
                    self.drive(0.0, 0.0, math.copysign(s.max_wz, alpha), dt)
                else:
                    v = s.max_vx * slow
                    w = 2 * v * math.sin(alpha) / ld
                    if abs(w) > s.max_wz:
                        v, w = v * s.max_wz / abs(w), math.copysign(s.max_wz, w)
                    self.drive(v, 0.0, w, dt)
                return False
        return self.finisher.step(dt)


# ----------------------------------------------------------------------------- joints
class JointMotion(Controller):
    """Move joints at a constant angular speed to their targets (targets may be computed lazily)."""

    slot = "joints"

    def __init__(self, robot: "Body", targets: dict[str, float] | None, speed: float):
        super().__init__()
        self.robot, self.targets, self.speed = robot, targets, speed

    def compute_targets(self) -> dict[str, float]:
        return self.targets or {}

    @property
    def joint_names(self) -> set[str]:
        return set(self.targets or ())

    def step(self, dt: float) -> bool:
        if self.targets is None:
            self.targets = self.compute_targets()
        r = self.robot
        done = True
        max_step = self.speed * dt
        for j, goal in self.targets.items():
            cur = r.q[j]
            d = goal - cur
            if abs(d) <= max_step:
                r.set_joint(j, goal)
            else:
                r.set_joint(j, cur + math.copysign(max_step, d))
                done = False
        r.update_lift()
        return done


class LookAt(JointMotion):
    def __init__(self, robot: "Body", point: tuple[float, float, float], speed: float):
        super().__init__(robot, None, speed)
        self.point = point

    @property
    def joint_names(self) -> set[str]:
        return {self.robot.spec.head_yaw, self.robot.spec.head_pitch}

    def compute_targets(self) -> dict[str, float]:
        return self.robot.head.solve(self.point)
