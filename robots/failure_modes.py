"""How the simulated robots fail like real ones (issue #17): the NAO's walk sways and its feet slip, the
Elektron's six skid-steered wheels slip (more on turns), cameras have sensor noise, motion blur and
auto-exposure, sonar and laser ranges are noisy.

Motion errors go into the TRUE pose, not the odometry: the odometry reports the commanded motion (what
the walk engine or the wheel encoders know), so it drifts from the truth by what slipped. (An
OdometryNoise given to World.add_robot still adds the odometry's own calibration errors on top.)

Every number below names its source; "ESTIMATE" marks one that is not a published figure.

Deterministic per seed: the robot's motion noise comes from one generator seeded with the house seed
and the robot's name; camera and range noise from generators seeded with the simulation step of the
reading (so how often, in wall time, someone polls a sensor changes nothing else).

Failure modes are ON by default. Ideal robots (exact motion, noise-free sensors, manual exposure), for
tests that need exactness: the environment variable RAPP_FAILURE_MODES=off, `with ideal_robots():`
around World.add_robot, or `robot.set_failure_modes(None)` on one robot before it moves."""
from __future__ import annotations

import contextlib
import math
import os
import zlib
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, cast

import numpy as np

from .odometry import wrap

if TYPE_CHECKING:
    from .body import Body, MovingJoints
    from .spec import RobotSpec

ENV = "RAPP_FAILURE_MODES"
_override: bool | None = None


# ============================================================================ parameters
@dataclass(frozen=True)
class NaoWalk:
    """The NAO's walk: a body swaying from foot to foot, and feet that slip a little at every step."""

    # nao_driver (ROS) nao_footsteps.py STEP_TIME = 0.5 s; NAOqi's walk at full step frequency makes ~2 steps/s
    step_period_s: float = 0.5
    # ESTIMATE from the linear inverted pendulum that NAOqi's walk uses (Aldebaran locomotion docs, after
    # Kajita et al. 2001): CoM height ~0.26 m (Tc = 0.163 s), feet +-0.05 m apart (hip offset 0.05 m),
    # 0.5 s steps -> the CoM swings +-0.05 (1 - 1/cosh(0.25/0.163)) = +-2.9 cm; double support lowers
    # it: 2 cm. Hornung et al. (IJHR 2014) and Cervera et al. (2012) name the NAO's sway as a localization problem
    sway_amplitude_m: float = 0.02
    # ESTIMATE: the sway is full from this fraction of top speed (slow final approaches sway less)
    sway_full_speed: float = 0.3
    # ESTIMATE, heading noise per full step (1 sigma). Hornung's NAO particle filter (humanoid_localization
    # nao_localization_laser.yaml, motion_noise/yaw 0.8 per m, applied per ~2 cm) gives 0.11 rad/sqrt(m);
    # particle filters inflate motion noise, we take about half: 0.015 rad per 6 cm step = 0.06 rad/sqrt(m).
    # Wirbel et al. (J. Intell. Syst. 2014): the NAO's walk "is affected by the feet slipping: the robot
    # orientation is often not precise"
    heading_std_rad: float = 0.015
    # ESTIMATE: extra heading noise of a turning step, a fraction of the step's rotation
    turn_heading_std: float = 0.05
    # ESTIMATE, foot slip per step along and across the step, a fraction of its length (1 sigma); the same
    # halving of Hornung's motion_noise/x,y (0.15 per m) gives ~0.01 m/sqrt(m) = 4 % of a 6 cm step
    slip_std: float = 0.04
    # ESTIMATE: steps come out this much shorter than commanded (feet slide back on a smooth floor)
    slip_bias: float = 0.03
    # the body moves by steps (issue 48.5; `--mechanical-drive`): within each step its speed rises from
    # double support and falls back (1 - cos over the step, the linear inverted pendulum's shape), so
    # it is ahead of and behind the walk engine's even odometry by turns; the torso rolls and bobs with
    # the steps (what the camera sees from, not what the robot's kinematics report); a walk that is
    # stopped finishes the step under way (NAOqi's stopMove ends the walk "on the next double support",
    # Aldebaran NAOqi 2.8 docs, locomotion control). Off: an even glide that stops dead, an upright torso
    steps: bool = False
    # ESTIMATE, the torso's roll toward the stance foot at full sway (rad, 1 amplitude): an inverted pendulum
    # rocking its 2 cm sway over the ankle at the CoM's 0.26 m would roll atan(0.02 / 0.26) = 4.4 deg;
    # NAOqi's walk moves the CoM with the hip and ankle roll joints and commands the torso upright
    # (moveConfig TorsoWx, default 0), so what rolls is the compliance of those joints under the whole
    # weight in single support: we take half, 2 deg. (B-Human's walk docs describe the torso "in a
    # pendulum-like swinging motion" from foot to foot; no published NAO figure was found)
    roll_rad: float = 0.035
    # ESTIMATE, the torso's height oscillation at the step frequency (m, 1 amplitude): the linear inverted
    # pendulum of NAOqi's walk keeps the CoM height constant (Kajita et al. 2001); what bobs is the stance
    # leg's sag under the whole weight in single support (lowest mid-step, highest in double support). A
    # human's CoM rises and falls 2-3 cm peak to peak (modern motion capture; 5 cm the classic figure) on
    # a 0.9 m leg: scaled to the NAO's 0.25 m leg, 6-8 mm peak to peak, a flat LIPM walk less: +-3 mm
    bob_m: float = 0.003


@dataclass(frozen=True)
class WheelSlip:
    """Six skid-steered wheels (paper 000 fig. 15b): a skid-steered robot must slide its wheels sideways to
    turn, so turns slip far more than straight driving (Mandow et al. 2007, experimental kinematics of
    skid-steer robots: the effective track width varies with floor and speed)."""

    trans_bias: float = 0.01  # ESTIMATE: straight runs come out 1 % short (tyre compliance, slip)
    trans_std: float = 0.005  # ESTIMATE: random slip of travelled distance, m per sqrt(m)
    rot_bias: float = 0.02  # ESTIMATE: turns come out 2 % short of what a calibrated odometry reports
    rot_std: float = 0.02  # ESTIMATE: random slip of turns, rad per sqrt(rad turned)
    heading_std: float = 0.005  # ESTIMATE: heading noise while driving (floor joints, rugs), rad per sqrt(m)
    # by wheel sides (issue 48.5; `--mechanical-drive`): each side's wheels slip by a ratio of their own
    # that wanders (an AR(1) over `side_slip_tau_s`), and a turn's effective track width (the skid) varies
    # about the one the odometry was calibrated with; heading errors then come from the sides' difference
    differential: bool = False
    track_m: float = 0.35  # the wheel sides' distance (the body sets its own: robots/elektron.py TRACK_M)
    side_slip_bias: float = 0.01  # ESTIMATE: both sides slip ~1 % (trans_bias)
    side_slip_std: float = 0.004  # ESTIMATE: each side's slip ratio wanders this much (1 sigma)
    side_slip_tau_s: float = 2.0  # ESTIMATE: ...over about this long (floor joints, rug edges)
    skid_bias: float = 0.01  # ESTIMATE: turns come out short by this besides the sides' slip (rot_bias in all)
    skid_std: float = 0.02  # ESTIMATE: a turn's effective track width varies ~2 % (Mandow et al. 2007, rot_std)


@dataclass(frozen=True)
class CameraNoise:
    """Sensor noise, motion blur and auto-exposure of a robot camera."""

    # NAO V4/V5 camera MT9M114 datasheet (Aptina/onsemi): SNR_MAX 37 dB -> shot-noise variance 10^-3.7 =
    # 2.0e-4 of full scale per unit signal; dynamic range 70.8 dB -> read noise 2.9e-4 of full scale.
    # The Elektron's camera is not named in the papers: the same figures are used (ESTIMATE)
    shot_variance: float = 2.0e-4
    read_std: float = 2.9e-4
    # ESTIMATE: exposure time at relative exposure 1.0: a 30 fps camera indoors exposes ~a frame time
    exposure_time_s: float = 0.03
    # NAOqi ALVideoDevice: camera parameter AutoExposition defaults to 1 (on) at power-up
    auto_exposure: bool = True
    # ESTIMATE: depth of the scene, to turn the camera's sideways speed into an angular rate for blur
    scene_depth_m: float = 2.0


@dataclass(frozen=True)
class RangeNoise:
    std_m: float  # standard deviation at short range
    relative_std: float = 0.0  # standard deviation as a fraction of the range, where larger
    resolution_m: float = 0.0  # readings are reported in steps of this


# Aldebaran NAO sonar docs: resolution 1 cm; ESTIMATE: 1 cm standard deviation
NAO_SONAR = RangeNoise(std_m=0.01, resolution_m=0.01)
# Hokuyo URG-04LX datasheet (the 240 deg, 5.6 m scanner the Elektron's spec matches): accuracy +-10 mm
# for 0.06-1 m, +-1 % of the range for 1-4 m (taken as one standard deviation); 1 mm resolution
ELEKTRON_LASER = RangeNoise(std_m=0.01, relative_std=0.01, resolution_m=0.001)


@dataclass(frozen=True)
class NaoFailures:
    walk: NaoWalk = field(default_factory=NaoWalk)
    camera: CameraNoise = field(default_factory=CameraNoise)
    sonar: RangeNoise = NAO_SONAR


@dataclass(frozen=True)
class ElektronFailures:
    wheels: WheelSlip = field(default_factory=WheelSlip)
    camera: CameraNoise = field(default_factory=CameraNoise)
    laser: RangeNoise = ELEKTRON_LASER



# ============================================================================ the switch
def enabled() -> bool:
    """Do new robots get failure modes? (`ideal_robots()` or RAPP_FAILURE_MODES=off: no.)"""
    if _override is not None:
        return _override
    value = os.environ.get(ENV, "on").strip().lower()
    if value in ("on", "1", "true", "yes", ""):
        return True
    if value in ("off", "0", "false", "no", "ideal"):
        return False
    raise ValueError(f"{ENV}={value!r}: use on or off")


@contextlib.contextmanager
def ideal_robots():
    """Robots added inside this block are ideal (exact motion, noise-free sensors)."""
    global _override
    saved, _override = _override, False
    try:
        yield
    finally:
        _override = saved


def defaults_for(spec: "RobotSpec"):
    """The failure-mode parameters of a body (its SPEC's `failures`), or None (ideal) when switched off."""
    return spec.failures if enabled() else None


def seed_sequence(seed: int, *names) -> list[int]:
    return [int(seed)] + [zlib.crc32(str(n).encode()) for n in names]


def reading_rng(robot: "Body", sensor: str) -> np.random.Generator:
    """A generator for one reading of `sensor`, seeded by the simulation step it is taken at."""
    clock = robot.world.clock
    step = int(round(clock.time / clock.step))
    return np.random.default_rng(seed_sequence(robot.world.plan.seed, "reading", robot.name, sensor) + [step])


# ============================================================================ locomotion
class Locomotion:
    """Drives the TRUE base pose with the motion errors of a robot; the odometry gets the commanded motion."""

    def __init__(self, spec: "RobotSpec", rng: np.random.Generator):
        self.spec, self.rng = spec, rng
        self.offset = 0.0  # lateral sway of the body off its gait line, m (robot frame, + = left)
        self.surface = 1.0  # the floor's slip under the robot, times the bare floor's

    def slip(self, dx: float, dy: float, dth: float, dt: float) -> tuple[float, float, float]:
        """The true displacement (robot frame) for a commanded one."""
        return dx, dy, dth

    def sway(self, vx: float, vy: float, wz: float, dt: float) -> float:
        """The body's lateral offset after this step."""
        return 0.0

    def sway_speed(self) -> float:
        """Sideways speed of the body from the sway now (m/s), for motion blur."""
        return 0.0

    def tilt(self) -> tuple[float, float]:
        """The torso's roll toward the stance foot now (rad, + = to the left) and its height off the
        standing one (m): what the camera sees from, not what the robot's kinematics report."""
        return 0.0, 0.0

    def tilt_rates(self) -> tuple[float, float]:
        """How fast the roll (rad/s) and the height (m/s) of `tilt` change now, for motion blur."""
        return 0.0, 0.0

    def finishing(self) -> bool:
        """A step is under way that no motion drives any more: the world steps it to its end (`tick`)."""
        return False

    def tick(self, robot: "Body", dt: float) -> None:
        """After each world step (pybullet thread): finish a step that a stopped walk left under way."""

    def drive(self, robot: "Body", vx: float, vy: float, wz: float, dt: float) -> bool:
        """One step of the base (as BaseEffector.drive, with the errors); True when an obstacle blocked it."""
        robot.base.command = (vx, vy, wz)
        x, y, th = robot.pose
        cdx, cdy = _arc(vx * dt, vy * dt, wz * dt)  # commanded, robot frame
        self.surface = robot.world.plan.slip_at(x, y)  # a rug (robots/lived_in.py): the feet slip more
        tdx, tdy, tdth = self.slip(vx * dt, vy * dt, wz * dt, dt)
        tdx, tdy = _arc(tdx, tdy, tdth)
        s0, c0 = math.sin(th), math.cos(th)
        gx, gy = x + self.offset * s0, y - self.offset * c0  # the gait line under the swaying body
        nth = wrap(th + tdth)
        gx, gy = gx + c0 * tdx - s0 * tdy, gy + s0 * tdx + c0 * tdy
        offset = self.sway(vx, vy, wz, dt)
        nx, ny = gx - offset * math.sin(nth), gy + offset * math.cos(nth)
        blocked = (nx, ny) != (x, y) and robot.collides(nx, ny)
        if blocked:  # pushing against an obstacle: the body turns on the spot at most
            nx, ny = x, y
        else:
            self.offset = offset
        robot.set_base_pose(nx, ny, nth)
        if blocked:
            robot.odometry.update(0.0, 0.0, wz * dt)
        else:
            robot.odometry.update(cdx, cdy, wz * dt)
        return blocked

    def settle(self, robot: "Body") -> None:
        """The motion ended: the body comes to rest over its gait line (the NAO stops in double support)."""
        if not self.offset:
            return
        x, y, th = robot.pose
        gx, gy = x + self.offset * math.sin(th), y - self.offset * math.cos(th)
        if not robot.collides(gx, gy):
            robot.set_base_pose(gx, gy, th)
            self.offset = 0.0


def _arc(dx: float, dy: float, dth: float) -> tuple[float, float]:
    """A displacement driven while turning by dth, in the frame at its start (mid-point heading)."""
    c, s = math.cos(dth / 2), math.sin(dth / 2)
    return c * dx - s * dy, s * dx + c * dy


class NaoGait(Locomotion):
    def __init__(self, spec: "RobotSpec", rng: np.random.Generator, walk: NaoWalk):
        super().__init__(spec, rng)
        self.walk = walk
        self.phase = 0.0  # sway phase (rad): one full swing per two steps
        self.amplitude = 0.0
        self.step_left = 0.0  # s of the current step still to walk
        self.noise = (0.0, 0.0, 0.0)  # this step's (along, across, heading) unit normals
        self.stride = (0.0, 0.0, 0.0)  # the velocity the step under way was last driven at (robot frame)
        self.driven = False  # a motion drove the body in this world step (mechanical drive)
        self.stopped = False  # the step under way is one a stopped walk finishes (mechanical drive)

    def effort(self, vx: float, vy: float, wz: float) -> float:
        s = self.spec
        return max(abs(vx) / s.max_vx, abs(vy) / s.max_vy if s.max_vy else 0.0, abs(wz) / s.max_wz)

    def slip(self, dx: float, dy: float, dth: float, dt: float) -> tuple[float, float, float]:
        if not (dx or dy or dth):
            return dx, dy, dth
        w = self.walk
        if self.step_left <= 0.0:  # a new step: its slip is drawn now
            self.step_left += w.step_period_s
            self.noise = tuple(self.rng.standard_normal(3))
        if w.steps:  # the body's speed over the step: 0 in double support, twice the mean mid-step
            done = 1.0 - max(self.step_left, 0.0) / w.step_period_s
            gait = 1.0 - math.cos(math.tau * min(1.0, done + 0.5 * dt / w.step_period_s))
            dx, dy = dx * gait, dy * gait
        self.step_left -= dt
        along, across, turn = self.noise
        step_effort = min(1.0, self.effort(dx / dt, dy / dt, dth / dt))
        d = math.hypot(dx, dy)
        if d > 0:
            ux, uy = dx / d, dy / d
            k = self.surface
            e_along, e_across = k * (-w.slip_bias + w.slip_std * along), k * w.slip_std * across
            dx, dy = dx + (e_along * ux - e_across * uy) * d, dy + (e_along * uy + e_across * ux) * d
        # heading noise of a whole step, spread over it: larger for bigger and turning steps
        fraction = dt / w.step_period_s
        step_turn = abs(dth) / fraction
        sigma = math.hypot(w.heading_std_rad * step_effort, w.turn_heading_std * step_turn)
        return dx, dy, dth + turn * sigma * fraction

    def sway(self, vx: float, vy: float, wz: float, dt: float) -> float:
        w = self.walk
        target = w.sway_amplitude_m * min(1.0, self.effort(vx, vy, wz) / w.sway_full_speed)
        self.amplitude += (target - self.amplitude) * min(1.0, dt / w.step_period_s)
        if self.amplitude > 1e-6:
            self.phase = (self.phase + math.pi * dt / w.step_period_s) % math.tau
        return self.amplitude * math.sin(self.phase)

    def sway_speed(self) -> float:
        return self.amplitude * math.pi / self.walk.step_period_s * math.cos(self.phase)

    def tilt(self) -> tuple[float, float]:
        w = self.walk
        if not w.steps or self.amplitude <= 1e-6:
            return 0.0, 0.0
        k = self.amplitude / w.sway_amplitude_m  # slow walks sway, roll and bob less
        # rolled over the stance foot with the sway; lowest mid-step (one leg carries all), highest in double support
        return k * w.roll_rad * math.sin(self.phase), k * w.bob_m * math.cos(2 * self.phase)

    def tilt_rates(self) -> tuple[float, float]:
        w = self.walk
        if not w.steps or self.amplitude <= 1e-6:
            return 0.0, 0.0
        k, f = self.amplitude / w.sway_amplitude_m, math.pi / w.step_period_s  # the phase's rate
        return k * w.roll_rad * f * math.cos(self.phase), -2 * k * w.bob_m * f * math.sin(2 * self.phase)

    def drive(self, robot: "Body", vx: float, vy: float, wz: float, dt: float) -> bool:
        if self.walk.steps:
            self.stopped = self.stopped and self.finishing()
            if self.stopped:  # a new motion starts once the stopped walk's step has landed
                vx, vy, wz = self.stride
            self.driven, self.stride = True, (vx, vy, wz)
        return super().drive(robot, vx, vy, wz, dt)

    def finishing(self) -> bool:
        return self.walk.steps and self.step_left > 1e-9 and any(self.stride)

    def tick(self, robot: "Body", dt: float) -> None:
        """A walk stopped mid-step (a stop, an emergency stop, a motion that failed) finishes the step: the
        swing foot is in the air and lands where it was going. The body walks the rest of the step at
        the velocity it was walked at, and the odometry counts it (the walk engine reports the step it
        made); then the body comes to rest over its feet. An obstacle ends it where it stands. A motion
        commanded meanwhile walks from the next step on (`drive`)."""
        if self.driven:
            self.driven = False
            return
        if not self.finishing():
            return
        robot.base.steps += 1  # walking, for the contact sensors
        self.stopped = True
        blocked = super().drive(robot, *self.stride, dt)
        if blocked or self.step_left <= 1e-9:
            self.step_left, self.stride = 0.0, (0.0, 0.0, 0.0)
            self.settle(robot)

    def settle(self, robot: "Body") -> None:
        if self.walk.steps:  # a motion that reached its goal: the walk engine landed its last step there
            self.step_left, self.stride, self.stopped = 0.0, (0.0, 0.0, 0.0), False
        super().settle(robot)
        if not self.offset:
            self.amplitude, self.phase = 0.0, 0.0


class SkidSteer(Locomotion):
    def __init__(self, spec: "RobotSpec", rng: np.random.Generator, wheels: WheelSlip):
        super().__init__(spec, rng)
        self.wheels = wheels
        self.side_slip = [0.0, 0.0]  # left, right: each side's slip ratio off the bias (differential)
        self.skid = 0.0  # the turn's effective track width off the calibrated one, a fraction

    def slip(self, dx: float, dy: float, dth: float, dt: float) -> tuple[float, float, float]:
        w = self.wheels
        if w.differential:
            return self._sides(dx, dth, dt)
        d, r = abs(dx), abs(dth)
        if d:
            dx = dx * (1 - w.trans_bias) + w.trans_std * math.sqrt(d) * self.rng.standard_normal()
        th_noise = 0.0
        if r:
            th_noise += w.rot_std * math.sqrt(r) * self.rng.standard_normal()
        if d:
            th_noise += w.heading_std * math.sqrt(d) * self.rng.standard_normal()
        return dx, dy, dth * (1 - w.rot_bias) + th_noise

    def _sides(self, dx: float, dth: float, dt: float) -> tuple[float, float, float]:
        """The wheel sides' travel from the commanded motion, each slipping; back to the body."""
        w = self.wheels
        if not (dx or dth):
            return 0.0, 0.0, 0.0
        keep = math.exp(-dt / w.side_slip_tau_s)  # AR(1): the slips wander, they do not jump
        kick = w.side_slip_std * math.sqrt(1.0 - keep * keep)
        self.side_slip = [keep * s + kick * self.rng.standard_normal() for s in self.side_slip]
        self.skid = keep * self.skid + w.skid_std * math.sqrt(1.0 - keep * keep) * self.rng.standard_normal()
        half = w.track_m / 2
        left, right = dx - dth * half, dx + dth * half  # what the encoders count, m
        k = self.surface
        left *= 1.0 - k * (w.side_slip_bias + self.side_slip[0])
        right *= 1.0 - k * (w.side_slip_bias + self.side_slip[1])
        return (left + right) / 2, 0.0, (right - left) / (w.track_m * (1.0 + k * (w.skid_bias + self.skid)))


def mechanical(params):
    """The failure modes `params` with the mechanical drive on (the NAO by steps, the Elektron by wheel
    sides); None stays None (an ideal robot)."""
    if isinstance(params, NaoFailures):
        return replace(params, walk=replace(params.walk, steps=True))
    if isinstance(params, ElektronFailures):
        return replace(params, wheels=replace(params.wheels, differential=True))
    return params


def make_locomotion(spec: "RobotSpec", params, seed: int, name: str) -> Locomotion | None:
    if params is None:
        return None
    rng = np.random.default_rng(seed_sequence(seed, "locomotion", name))
    if isinstance(params, NaoFailures):
        return NaoGait(spec, rng, params.walk)
    if isinstance(params, ElektronFailures):
        return SkidSteer(spec, rng, params.wheels)
    raise TypeError(f"no locomotion errors for {type(params).__name__}")


# ============================================================================ range sensors
def noisy_ranges(ranges: np.ndarray, noise: RangeNoise, rng: np.random.Generator, range_min: float,
                 range_max: float) -> np.ndarray:
    """Ranges with noise; rays that hit nothing stay at range_max (no echo is no echo)."""
    r = np.asarray(ranges, float)
    hit = r < range_max
    sigma = np.maximum(noise.std_m, noise.relative_std * r)
    out = r + sigma * rng.standard_normal(r.shape)
    if noise.resolution_m:
        out = np.round(out / noise.resolution_m) * noise.resolution_m
    out = np.clip(out, range_min, range_max)
    return np.where(hit, out, r)


def camera_motion(robot: "Body", depth_m: float, link: str | None = None) -> tuple[float, float]:
    """Angular rates (rad/s, image horizontal and vertical) of the scene in a camera (on `link`) now:
    the base's turn and sideways speed, the NAO's sway, the roll and bob of its torso and the head
    joints' motion (pybullet thread)."""
    s = robot.spec
    wh = wv = 0.0
    base = robot.controllers.get("base")  # (controllers change in the event loop's thread: read once)
    loco = robot.locomotion
    vx = vy = 0.0
    if base is not None and not base.done and not base.cancelled:
        vx, vy, wz = robot.base.command
        wh += wz
    elif loco is not None and loco.finishing():  # a stopped walk finishing its step
        vx, vy, wz = robot.base.command
        wh += wz
    if loco is not None:
        vy += loco.sway_speed()
        roll_rate, bob_rate = loco.tilt_rates()
        if (roll_rate or bob_rate) and link is not None:  # the head swings sideways with the roll, and bobs
            vy += roll_rate * (robot.link_pose(link)[2, 3] - robot.tilt_pivot_z())
            wv += bob_rate / depth_m
    yaw = robot.q.get(s.head_yaw, 0.0)
    wh += (-vx * math.sin(yaw) + vy * math.cos(yaw)) / depth_m
    for key, ctrl in list(robot.controllers.items()):  # head joints on their way to a target
        targets = getattr(ctrl, "targets", None)
        if not key.startswith("joints") or ctrl.done or ctrl.cancelled or not targets:
            continue
        for joint, goal in targets.items():
            if joint in (s.head_yaw, s.head_pitch) and abs(goal - robot.q.get(joint, goal)) > 1e-6:
                rate = math.copysign(cast("MovingJoints", ctrl).speed, goal - robot.q[joint])
                if joint == s.head_yaw:
                    wh += rate
                else:
                    wv += rate
    return wh, wv
