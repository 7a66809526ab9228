"""The SDK's planar pose EKF (odometry predicts, landmark fixes correct): agents/pose_ekf.py, the same filter
the Core localizes with (agents/core_localizer.py; paper 001 puts relative localization in the Core). A RApp
imports it from here and may still run its own, as rapps/sdk/localize.py does.

    ekf = PoseEKF((x, y, theta), std_m=0.5, std_rad=0.3)
    ekf.predict_between(odom_before, odom_after, ODOMETRY["nao"], travelled_m=1.2, turned_rad=0.4)
    ekf.update(fix, std_m=0.01, std_rad=0.004, gate=CHI2_3DOF_99)
"""
from agents.pose_ekf import CHI2_3DOF_99, ODOMETRY, OdometryModel, PoseEKF, compose, relative, wrap

__all__ = ["CHI2_3DOF_99", "ODOMETRY", "OdometryModel", "PoseEKF", "compose", "relative", "wrap"]
