"""A planar pose EKF for the Core and RApps: odometry predicts, landmark fixes correct (paper 001 sec. 3: "landmark
(QR-code) based global localization and Extended Kalman Filter relative localization").

The state is the robot's pose (x, y, theta) in the map frame with its 3x3 covariance. `predict` moves
it by an odometry displacement (robot frame) and grows the covariance by the odometry's error model;
`update` fuses a pose fix (a QR-code localization) with its covariance, optionally refusing a fix too
far from the prediction (Mahalanobis gate). numpy only; each robot type's odometry model comes from
ontology/robot_types.py.

    ekf = PoseEKF((x, y, theta), std_m=0.5, std_rad=0.3)          # the start pose, hardly trusted
    ekf.predict_between(odom_before, odom_after, ODOMETRY["nao"], travelled_m=1.2, turned_rad=0.4)
    ekf.update(fix, std_m=0.01, std_rad=0.004, gate=CHI2_3DOF_99)
    x, y, theta = ekf.pose
"""
from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from ontology.robot_types import ROBOT_TYPES, Odometry

CHI2_3DOF_99 = 11.34  # chi-square, 3 degrees of freedom, 99 %: a consistent fix is refused 1 time in 100


def wrap(a: float) -> float:
    return math.remainder(a, math.tau)


def relative(a: ArrayLike, b: ArrayLike) -> tuple[float, float, float]:
    """Pose b in the frame of pose a (both (x, y, theta)): the displacement from a to b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    dx, dy = float(b[0] - a[0]), float(b[1] - a[1])
    c, s = math.cos(a[2]), math.sin(a[2])
    return c * dx + s * dy, -s * dx + c * dy, wrap(float(b[2] - a[2]))


def compose(a: ArrayLike, d: ArrayLike) -> tuple[float, float, float]:
    """Pose a moved by the displacement d (in a's frame)."""
    a, d = np.asarray(a, float), np.asarray(d, float)
    c, s = math.cos(a[2]), math.sin(a[2])
    return (float(a[0] + c * d[0] - s * d[1]), float(a[1] + s * d[0] + c * d[1]), wrap(float(a[2] + d[2])))


@dataclass(frozen=True)
class OdometryModel(Odometry):
    """How wrong a robot's odometry may be (1 sigma), as a RApp developer calibrates it: random parts grow
    with the square root of the motion, systematic parts (slip, drift) with the motion itself (the
    fields of ontology.robot_types.Odometry)."""

    def covariance(self, d: float, r: float) -> np.ndarray:
        """Robot-frame covariance of a displacement over `d` m and `r` rad, straight ahead: slip along it;
        sideways, heading errors made along the way put the end point off by a third of the squared
        heading error times d^2."""
        var_h = self.heading_std ** 2 * d + (self.heading_drift * d) ** 2
        var_t = self.trans_std ** 2 * d + (self.trans_rel * d) ** 2
        var_th = self.rot_std ** 2 * r + (self.rot_rel * r) ** 2 + var_h
        return np.diag([var_t, self.trans_std ** 2 * d + var_h * d * d / 3, var_th])


class _OdometryByType(Mapping[str, OdometryModel]):
    """What a RApp assumes of each robot type's odometry: the `odometry` row of
    ontology/robot_types.py, read there at each look-up (a type added to the table has its model)."""

    def __getitem__(self, robot_type: str) -> OdometryModel:
        return OdometryModel(**asdict(ROBOT_TYPES[robot_type].odometry))

    def __iter__(self) -> Iterator[str]:
        return iter(ROBOT_TYPES)

    def __len__(self) -> int:
        return len(ROBOT_TYPES)


ODOMETRY: Mapping[str, OdometryModel] = _OdometryByType()


class PoseEKF:
    def __init__(self, pose: ArrayLike, std_m: float = 0.5, std_rad: float = 0.3, cov: ArrayLike | None = None):
        start = np.asarray(pose, float)
        self.x = np.array([float(start[0]), float(start[1]), wrap(float(start[2]))])
        self.P = (np.asarray(cov, float).copy() if cov is not None
                  else np.diag([std_m ** 2, std_m ** 2, std_rad ** 2]))
        if self.P.shape != (3, 3) or not np.all(np.isfinite(self.P)):
            raise ValueError(f"bad covariance {self.P!r}")

    @property
    def pose(self) -> tuple[float, float, float]:
        return float(self.x[0]), float(self.x[1]), float(self.x[2])

    @property
    def std_m(self) -> float:
        """Position standard deviation along the worst direction."""
        return float(math.sqrt(max(np.linalg.eigvalsh(self.P[:2, :2]).max(), 0.0)))

    @property
    def std_rad(self) -> float:
        return float(math.sqrt(max(self.P[2, 2], 0.0)))

    def cross_track_std(self, distance: float, model: OdometryModel) -> float:
        """Predicted sideways standard deviation after driving `distance` m straight ahead from here:
        the position's and heading's uncertainty now plus the odometry's own (how long a leg may be)."""
        th = self.x[2]
        side = np.array([-math.sin(th), math.cos(th)])
        var = float(side @ self.P[:2, :2] @ side) + self.P[2, 2] * distance ** 2
        return math.sqrt(var + model.covariance(distance, 0.0)[1, 1])

    def predict(self, delta: ArrayLike, model: OdometryModel, travelled_m: float | None = None,
                turned_rad: float | None = None) -> None:
        """Move by the odometry displacement `delta` (dx, dy, dtheta in the robot frame). The error grows
        with the motion actually made, which may be longer than the displacement (a path with corners,
        a turn and back): pass `travelled_m` and `turned_rad` when known."""
        dx, dy, dth = (float(v) for v in np.asarray(delta, float))
        d = max(math.hypot(dx, dy), travelled_m or 0.0)
        r = max(abs(dth), turned_rad or 0.0)
        th = self.x[2]
        c, s = math.cos(th), math.sin(th)
        F = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
        G = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        self.x = np.array(compose(self.x, (dx, dy, dth)))
        self.P = F @ self.P @ F.T + G @ model.covariance(d, r) @ G.T

    def predict_between(self, odom_before: ArrayLike, odom_after: ArrayLike, model: OdometryModel,
                        **kw: float | None) -> None:
        """Predict with the displacement between two odometry poses (the robot's own estimate)."""
        self.predict(relative(odom_before, odom_after), model, **kw)

    def mahalanobis2(self, z: ArrayLike, R: ArrayLike) -> float:
        v = self._innovation(z)
        return float(v @ np.linalg.solve(self.P + np.asarray(R, float), v))

    def _innovation(self, z: ArrayLike) -> np.ndarray:
        v: np.ndarray = np.asarray(z, float)[:3] - self.x
        v[2] = wrap(float(v[2]))
        return v

    def update(self, z: ArrayLike, std_m: float | None = None, std_rad: float | None = None, R: ArrayLike | None = None,
               gate: float | None = None) -> bool:
        """Fuse a pose fix z = (x, y, theta) with standard deviations (or covariance R). With `gate`, a
        fix whose squared Mahalanobis distance from the prediction exceeds it is refused: False."""
        if R is None:
            if std_m is None or std_rad is None or not (std_m > 0 and std_rad > 0):
                raise ValueError("update needs std_m and std_rad > 0, or R")
            R = np.diag([std_m ** 2, std_m ** 2, std_rad ** 2])
        R = np.asarray(R, float)
        if not np.all(np.isfinite(R)) or not all(math.isfinite(float(v)) for v in np.asarray(z, float)[:3]):
            raise ValueError("update needs a finite fix and covariance")
        v = self._innovation(z)
        S = self.P + R
        if gate is not None and float(v @ np.linalg.solve(S, v)) > gate:
            return False
        K = self.P @ np.linalg.inv(S)
        self.x = self.x + K @ v
        self.x[2] = wrap(float(self.x[2]))
        I_K = np.eye(3) - K
        self.P = I_K @ self.P @ I_K.T + K @ R @ K.T  # Joseph form: stays symmetric positive definite
        return True
