"""Virtual effectors: mobile base, joints (incl. postures), head (look-at solver), loudspeaker.
Methods touching pybullet run in the world's pybullet thread (controllers call them)."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pybullet as p

from .errors import InvalidArgument, UnsupportedOperation
from .odometry import wrap

if TYPE_CHECKING:
    from .robot import Robot


class BaseEffector:
    """Kinematic base: velocity in the robot frame, integrated with collision checks."""

    def __init__(self, robot: "Robot"):
        self.robot, self.spec = robot, robot.spec
        self.command = (0.0, 0.0, 0.0)  # the velocity of the last step driven (robot frame)

    def check_velocity(self, vx: float, vy: float, wz: float) -> tuple[float, float, float]:
        s = self.spec
        if vy != 0.0 and not s.holonomic:
            raise UnsupportedOperation(
                f"{s.kind} has a differential drive (non-holonomic): lateral velocity y={vy} is not possible; "
                "use x (forward) and theta (rotation) only")
        return (float(np.clip(vx, -s.max_vx, s.max_vx)), float(np.clip(vy, -s.max_vy, s.max_vy)),
                float(np.clip(wz, -s.max_wz, s.max_wz)))

    def drive(self, vx: float, vy: float, wz: float, dt: float) -> bool:
        """Advance the true pose by one step; returns True when an obstacle blocked the translation."""
        r = self.robot
        self.command = (vx, vy, wz)
        x, y, th = r.pose
        thm = th + wz * dt / 2
        dxw = (vx * math.cos(thm) - vy * math.sin(thm)) * dt
        dyw = (vx * math.sin(thm) + vy * math.cos(thm)) * dt
        nth = wrap(th + wz * dt)
        blocked = False
        if (dxw or dyw) and r.collides(x + dxw, y + dyw):
            blocked, dxw, dyw = True, 0.0, 0.0
        r.set_base_pose(x + dxw, y + dyw, nth)
        c, s = math.cos(th), math.sin(th)
        r.odometry.update(c * dxw + s * dyw, -s * dxw + c * dyw, wrap(nth - th))
        return blocked


class JointsEffector:
    def __init__(self, robot: "Robot"):
        self.robot, self.spec = robot, robot.spec

    @property
    def names(self) -> list[str]:
        return [n for n in self.robot.limits if n not in self.spec.hidden_joints]

    def targets(self, joints: list[str], angles: list[float]) -> dict[str, float]:
        if len(joints) != len(angles):
            raise InvalidArgument(f"{len(joints)} joints but {len(angles)} angles")
        out = {}
        for j, a in zip(joints, angles):
            if j not in self.names:
                raise InvalidArgument(f"unknown joint {j!r} on {self.spec.kind} (known: {', '.join(self.names)})")
            lo, hi = self.robot.limits[j]
            out[j] = float(np.clip(a, lo, hi))
        return out

    def posture(self, name: str) -> dict[str, float]:
        for k, v in self.spec.postures.items():
            if k.lower() == name.lower():
                return dict(v)
        raise InvalidArgument(f"unknown posture {name!r} on {self.spec.kind} "
                              f"(known: {', '.join(self.spec.postures)})")

    def speed(self, fraction: float) -> float:
        if not 0 < fraction <= 1:
            raise InvalidArgument(f"speed must be in (0, 1], got {fraction}")
        return self.spec.joint_speed * fraction


class HeadEffector:
    """Look-at solver: head yaw/pitch that put a global point on the look camera's optical axis,
    using the robot's ESTIMATED pose (so the result is only as good as localization)."""

    def __init__(self, robot: "Robot"):
        self.robot, self.spec = robot, robot.spec

    def solve(self, target: tuple[float, float, float]) -> dict[str, float]:
        r, s = self.robot, self.spec
        x, y, th = r.odometry.estimate
        dx, dy = target[0] - x, target[1] - y
        tx, ty = math.cos(th) * dx + math.sin(th) * dy, -math.sin(th) * dx + math.cos(th) * dy
        tz = target[2]
        # pan joint origin in the base frame (kinematics are known exactly; base frame is at the floor)
        T_base = r.link_pose(r.root_link)
        pan_parent = r.link_pose(r.joint_parent[s.head_yaw])
        pan_origin = pan_parent @ r.joint_offset(s.head_yaw)
        P = (np.linalg.inv(T_base) @ pan_origin)[:3, 3]
        tilt_off = r.joint_offset(s.head_pitch)[:3, 3]
        cam_link = next(c.link for c in s.cameras if c.name == s.look_camera)
        cam_off = r.joint_offset_of_link(cam_link)[:3, 3]
        yaw = math.atan2(ty - P[1], tx - P[0])
        D = math.hypot(tx - P[0], ty - P[1]) - tilt_off[0]
        H = tz - P[2] - tilt_off[2]
        pitch = -math.atan2(H, D)
        for _ in range(8):  # camera offset from the tilt axis: fixed-point iteration
            cx = cam_off[0] * math.cos(pitch) + cam_off[2] * math.sin(pitch)
            cz = -cam_off[0] * math.sin(pitch) + cam_off[2] * math.cos(pitch)
            pitch = -math.atan2(H - cz, D - cx)
        lo_y, hi_y = r.limits[s.head_yaw]
        lo_p, hi_p = r.limits[s.head_pitch]
        return {s.head_yaw: float(np.clip(yaw, lo_y, hi_y)), s.head_pitch: float(np.clip(pitch, lo_p, hi_p))}


class Loudspeaker:
    """The robot's loudspeaker: what was said (text, with simulation time) and the audio it played,
    which also sounds in the house (a source at the robot's head, heard by every microphone)."""

    SECONDS_PER_WORD = 0.35
    FULL_SCALE_DB_SPL = 88.0  # at 1 m, a full-scale sine: eSpeak's speech comes out near 66 dB
    KEEP = 32  # recent clips kept for inspection

    def __init__(self, robot: "Robot"):
        self.robot = robot
        self.spoken: list[tuple[float, str]] = []
        self.played: list[tuple[float, str | None, np.ndarray]] = []

    def duration(self, text: str) -> float:
        """An estimate without audio (a robot whose speech is not synthesised)."""
        return 0.3 + self.SECONDS_PER_WORD * len(text.split())

    def say(self, text: str, t: float) -> None:
        self.spoken.append((t, text))

    def position(self) -> tuple[float, float, float]:
        x, y, _ = self.robot.pose
        return x, y, self.robot.spec.collision_height + 0.05

    def play(self, pcm: np.ndarray, t: float, text: str | None = None) -> float:
        """Play 16 kHz int16 audio from simulation time `t` into the house; its duration in seconds."""
        from .sound import SAMPLE_RATE, house_sound
        if text is not None:
            self.say(text, t)
        self.played = (self.played + [(t, text, pcm)])[-self.KEEP:]
        house = house_sound(self.robot.world)
        house.prune(t - 60.0)
        house.play(f"loudspeaker:{self.robot.name}:{len(self.spoken)}:{t:.3f}", self.position(), pcm, t,
                   level_db=None, full_scale_db=self.FULL_SCALE_DB_SPL)
        return len(pcm) / SAMPLE_RATE

    def sounding_until(self, t0: float, t1: float, tail: float = 0.0) -> float | None:
        """When the sound it played within [t0, t1] of simulation time ends (+ `tail`, e.g. its way to a
        microphone), or None: silent then."""
        from .sound import SAMPLE_RATE
        recent = [(start, start + len(pcm) / SAMPLE_RATE + tail) for start, _, pcm in self.played[-8:]]
        ends = [end for start, end in recent if start <= t1 and end > t0]
        return max(ends) if ends else None

    def silence(self, t: float) -> None:
        """Cut off what is still playing at simulation time `t` (the emergency stop)."""
        from .sound import house_sound
        house = house_sound(self.robot.world)
        prefix = f"loudspeaker:{self.robot.name}:"
        for source_id, source in list(house.sources.items()):
            if source_id.startswith(prefix) and (source.end() or math.inf) > t:
                house.remove(source_id)


def check_speech(robot: "Robot") -> Loudspeaker:
    if robot.loudspeaker is None:
        raise UnsupportedOperation(f"{robot.spec.kind} has no speech synthesis (no loudspeaker); say is not available")
    return robot.loudspeaker


_ = p  # pybullet used by callers through robot helpers
