"""Virtual effectors: mobile base, joints (incl. postures), head (look-at solver); the loudspeaker is
robots/loudspeaker.py. Methods touching pybullet run in the world's pybullet thread (controllers call
them)."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from .pybullet_quiet import p

from .errors import InvalidArgument, UnsupportedOperation
from .odometry import wrap

if TYPE_CHECKING:
    from .body import Body


class BaseEffector:
    """Kinematic base: velocity in the robot frame, integrated with collision checks."""

    def __init__(self, robot: "Body"):
        self.robot, self.spec = robot, robot.spec
        self.command = (0.0, 0.0, 0.0)  # the velocity of the last step driven (robot frame)
        self.steps = 0  # steps driven so far (controllers.drive_base): the contact sensors see whether it walks

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
    def __init__(self, robot: "Body"):
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

    def __init__(self, robot: "Body"):
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


_ = p  # pybullet used by callers through robot helpers
