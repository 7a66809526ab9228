"""Odometry: the robot's own pose estimate, integrated from the motion the base was commanded (what a
walk engine or wheel encoders report) plus configurable drift (OdometryNoise: calibration errors).

The estimate diverges from ground truth unless corrected with ``set`` (what localization does through
RobotAPI.set_global_pose): by this drift, and by what the robot's failure modes (robots/failure_modes.py:
foot slip, wheel slip) made the true motion differ from the commanded one."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


@dataclass(frozen=True)
class OdometryNoise:
    trans_std: float = 0.0  # random walk of position, m per sqrt(m travelled)
    rot_std: float = 0.0  # random walk of heading, rad per sqrt(rad turned + m travelled)
    trans_scale: float = 0.0  # systematic relative error of travelled distance (wheel radius error)
    rot_drift: float = 0.0  # systematic heading drift, rad per m travelled

    @classmethod
    def typical(cls) -> "OdometryNoise":
        return cls(trans_std=0.01, rot_std=0.02, trans_scale=0.02, rot_drift=0.05)

    @property
    def enabled(self) -> bool:
        return any((self.trans_std, self.rot_std, self.trans_scale, self.rot_drift))


class Odometry:
    """Integrates robot-frame displacements (dx, dy, dtheta) into the estimated global pose."""

    def __init__(self, pose: tuple[float, float, float], noise: OdometryNoise | None = None,
                 rng: np.random.Generator | None = None):
        self.estimate = tuple(map(float, pose))
        self.noise = noise or OdometryNoise()
        self.rng = rng or np.random.default_rng(0)
        self.travelled = self.turned = 0.0  # all the motion counted (m, rad), as wheel encoders or steps count it

    def set(self, pose: tuple[float, float, float]) -> None:
        self.estimate = (float(pose[0]), float(pose[1]), wrap(float(pose[2])))

    def update(self, dx: float, dy: float, dth: float) -> None:
        d = math.hypot(dx, dy)
        self.travelled += d
        self.turned += abs(dth)
        n = self.noise
        if n.enabled and (d > 0 or dth != 0):
            s = 1.0 + n.trans_scale
            dx, dy = dx * s, dy * s
            if n.trans_std and d > 0:
                dx += self.rng.normal(0, n.trans_std * math.sqrt(d))
                dy += self.rng.normal(0, n.trans_std * math.sqrt(d))
            dth += n.rot_drift * d
            if n.rot_std:
                dth += self.rng.normal(0, n.rot_std * math.sqrt(abs(dth) + d))
        x, y, th = self.estimate
        c, s_ = math.cos(th), math.sin(th)
        self.estimate = (x + c * dx - s_ * dy, y + s_ * dx + c * dy, wrap(th + dth))
