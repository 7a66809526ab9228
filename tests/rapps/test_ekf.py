"""The RApp SDK's pose EKF (rapps/sdk/ekf.py): odometry predictions grow the covariance, QR fixes pull the
pose to them and shrink it, a fix far off the prediction is refused by the gate; and the hazard RApp's
leg length from it."""
import math

import numpy as np
import pytest

from rapps.sdk.localize import Localizer
from rapps.sdk.ekf import CHI2_3DOF_99, ODOMETRY, PoseEKF, compose, relative

NAO = ODOMETRY["nao"]


def test_converges_to_a_qr_fix():
    ekf = PoseEKF((1.0, 2.0, 0.3), std_m=0.5, std_rad=0.3)  # a start pose hardly trusted
    fix = (1.2, 1.9, 0.25)
    assert ekf.update(fix, std_m=0.01, std_rad=0.005)
    assert np.allclose(ekf.pose, fix, atol=0.002)
    assert ekf.std_m == pytest.approx(0.01, rel=0.01) and ekf.std_rad < 0.0051
    for _ in range(3):  # more fixes of the same pose: more certain, still there
        ekf.update(fix, std_m=0.01, std_rad=0.005)
    assert np.allclose(ekf.pose, fix, atol=1e-4) and ekf.std_m < 0.006


def test_a_fix_is_weighed_against_the_prediction():
    ekf = PoseEKF((0.0, 0.0, 0.0), std_m=0.02, std_rad=0.01)
    ekf.update((0.02, 0.0, 0.0), std_m=0.02, std_rad=0.01)  # as certain as the prediction: half way
    assert ekf.pose[0] == pytest.approx(0.01, abs=1e-9)


def test_with_odometry_only_the_covariance_grows():
    ekf = PoseEKF((0.0, 0.0, 0.0), std_m=0.01, std_rad=0.005)
    stds = [(ekf.std_m, ekf.std_rad)]
    for _ in range(5):
        ekf.predict((0.5, 0.0, 0.1), NAO)
        stds.append((ekf.std_m, ekf.std_rad))
    assert all(b[0] > a[0] and b[1] > a[1] for a, b in zip(stds, stds[1:]))
    assert stds[-1][0] > 0.05  # 2.5 m of walking: several cm
    assert np.allclose(np.linalg.eigvalsh(ekf.P) > 0, True) and np.allclose(ekf.P, ekf.P.T)


def test_prediction_composes_in_the_robot_frame():
    ekf = PoseEKF((1.0, 1.0, math.pi / 2), std_m=0.01, std_rad=0.01)
    ekf.predict((1.0, 0.5, 0.2), NAO)  # forward is +y in the map, left is -x
    assert np.allclose(ekf.pose, (0.5, 2.0, math.pi / 2 + 0.2))
    before, after = (2.0, -1.0, 3.0), (1.5, -0.2, -3.0)
    assert np.allclose(compose(before, relative(before, after)), after)


def test_a_longer_path_than_the_displacement_grows_it_more():
    a, b = PoseEKF((0, 0, 0), 0.01, 0.005), PoseEKF((0, 0, 0), 0.01, 0.005)
    a.predict((0.0, 0.0, 0.0), NAO)  # there and back: no displacement
    b.predict((0.0, 0.0, 0.0), NAO, travelled_m=2.0, turned_rad=math.pi)
    assert b.std_m > 2 * a.std_m and b.std_rad > 5 * a.std_rad


def test_gate_refuses_a_fix_far_off_the_prediction():
    ekf = PoseEKF((0.0, 0.0, 0.0), std_m=0.03, std_rad=0.02)
    assert not ekf.update((0.5, 0.0, 0.0), std_m=0.03, std_rad=0.02, gate=CHI2_3DOF_99)  # 12 sigma off
    assert ekf.pose == (0.0, 0.0, 0.0)
    assert ekf.update((0.04, 0.0, 0.0), std_m=0.03, std_rad=0.02, gate=CHI2_3DOF_99)  # one sigma: taken
    # headings wrap: pi - 0.01 and -pi + 0.01 are 0.02 apart, not 2 pi
    ekf = PoseEKF((0.0, 0.0, math.pi - 0.01), std_m=0.03, std_rad=0.02)
    assert ekf.update((0.0, 0.0, -math.pi + 0.01), std_m=0.03, std_rad=0.02, gate=CHI2_3DOF_99)
    assert abs(math.remainder(ekf.pose[2] - math.pi, math.tau)) < 0.011


def test_bad_input_is_refused():
    ekf = PoseEKF((0.0, 0.0, 0.0))
    with pytest.raises(ValueError):
        ekf.update((1.0, 0.0, 0.0), std_m=0.0, std_rad=0.01)
    with pytest.raises(ValueError):
        ekf.update((float("nan"), 0.0, 0.0), std_m=0.01, std_rad=0.01)
    with pytest.raises(ValueError):
        PoseEKF((0, 0, 0), cov=np.eye(2))


class _Task:
    """What Localizer.leg_length asks of its task: the robot type."""

    def __init__(self, kind):
        self.robot_info = type("RobotInfo", (), {"robot_type": kind})()
        self.params = {}


def test_leg_length_keeps_the_predicted_sideways_error_within_budget():
    nao, elektron = Localizer(_Task("nao")), Localizer(_Task("elektron"))
    assert nao.leg_length(1.0, 0.035) == 1.0  # no filter yet: the parameter
    for loc in (nao, elektron):
        loc.ekf = PoseEKF((0, 0, 0), std_m=0.008, std_rad=0.003)  # just localized
    legs = nao.leg_length(1.0, 0.035), elektron.leg_length(1.0, 0.035)
    assert 0.4 < legs[0] < 1.0 and legs[1] == 1.0  # the NAO's walk slips more than the wheels
    assert nao.ekf.cross_track_std(legs[0], NAO) == pytest.approx(0.035, abs=1e-4)
    nao.ekf.predict((0.0, 0.0, 0.0), NAO, travelled_m=1.0)  # no fix since: shorter still
    assert nao.leg_length(1.0, 0.035) < legs[0]
