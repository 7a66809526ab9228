"""The Cloud Agent's part of the SDK's landmark localization (paper 001 fig. 6: QR-marker global
localization): find the home's codes in a frame, then solve the robot's pose from every code seen.

A RApp gets it by making its Cloud part one (`cloud_entry_point: my_rapp.cloud:MyCloud` with
`class MyCloud(LandmarkCloud)`): the task's `await self.localize()` calls it (docs/sdk.md).

A first estimate: with two or more distinct landmarks, from their centres only (a weighted 2-D rigid
fit of robot-frame to map positions): ranges and bearings of codes are far more accurate than a
single code's orientation; with one landmark, that code's full pose. Then the planar pose (x, y,
theta) is refined by minimizing the reprojection error of every corner of every code in every frame
(the camera height, roll and pitch are known from the robot's kinematics, so only three unknowns
remain: a single code's heading is no longer the ill-conditioned 6-DOF one)."""
from __future__ import annotations

import asyncio
import math
from typing import cast

import cv2
import numpy as np
from scipy.optimize import least_squares

from ontology.landmarks import ONTOLOGY, Localization, Observation, Observations, Observe, SolvePose
from ontology.services.common import Pose2D

from . import CloudService
from . import vision as L
from .landmarks import View, observed_views, pose_std, residuals, rigid_fit


def observe(req: Observe) -> Observations:
    img = L.decode_image(req.image_b64)
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    K, dist = L.camera_matrix(req.camera)
    T_robot_cam = np.asarray(req.camera_to_robot, float)
    items = []
    for text, corners in L.detect_qr(img, req.expect):
        lm = req.landmarks.get(text)
        if lm is None:
            continue
        refined = L.refine_corners(gray, corners).reshape(4, 2)
        solutions = code_poses(refined, lm.size_m, K, dist)  # each landmark at its own printed size
        T_cam_code = solutions[0]
        d = float(np.linalg.norm(T_cam_code[:3, 3]))
        if d > req.max_distance_m:
            continue
        poses = [dict(zip(("x", "y", "theta"), L.planar(L.robot_pose_from_code(T, T_robot_cam, lm))))
                 for T in solutions]
        centre = (T_robot_cam @ T_cam_code[:, 3])[:3]
        items.append(Observation(text=text, in_robot=centre.tolist(), poses=poses, distance_m=d,
                                 corners=refined.tolist(), camera=req.camera, camera_to_robot=req.camera_to_robot))
    return Observations(items=items)


def code_poses(corners: np.ndarray, size: float, K: np.ndarray, dist: np.ndarray) -> list[np.ndarray]:
    """Both IPPE solutions (code -> camera), lowest reprojection error first: far or small planar
    codes are ambiguous, a wrong flip turns the robot heading by tens of degrees."""
    n, rvecs, tvecs, _ = cv2.solvePnPGeneric(L.code_corners_3d(size), corners.reshape(4, 1, 2).astype(np.float64),
                                             K, dist, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    if not n:
        return [L.code_pose(corners, size, K, dist)]
    return [L.transform(cv2.Rodrigues(r)[0], t) for r, t in zip(rvecs, tvecs)]


def refine(starts: list[tuple[float, float, float]], views: list[View]) -> tuple[tuple[float, float, float], float] | None:
    """Planar robot pose minimizing the corners' reprojection error, from the best of the start poses;
    (pose, rms px) or None without usable views."""
    if not views:
        return None
    best = None
    for q0 in starts:
        sol = least_squares(residuals, np.asarray(q0, float), args=(views,), loss="soft_l1", f_scale=2.0,
                            x_scale=[0.1, 0.1, 0.02])
        rms = float(np.sqrt(np.mean(residuals(sol.x, views) ** 2)))
        if best is None or rms < best[1]:
            best = ((float(sol.x[0]), float(sol.x[1]), math.remainder(float(sol.x[2]), math.tau)), rms)
    return best


SINGLE_MAX_M = 2.5  # one code farther than this fixes the pose too poorly (tens of cm): keep odometry
# above this a multi-code fit drops a code and tries again. Replayed from the realism tables (1280x960): fits of
# right codes only were within 1 px rms in 611 of 638 (98 % of those without worn codes), fits that kept a moved
# code above it in 13 of 17
GOOD_RMS_PX = 1.0


def solve_pose(req: SolvePose) -> Localization:
    loc = _solve(req)
    while loc.found and len(loc.markers) > 1 and (loc.rms_px is None or loc.rms_px > GOOD_RMS_PX):
        # one code disagrees (partly hidden, seen too obliquely, moved since the map was made); a fit that
        # did not converge at all (no rms) is the same, only worse
        if len(loc.markers) >= 3:  # the code whose leaving out fits the rest best: a moved code pulls the
            # fit toward itself, and the worst residual at that fit can be a code that was right
            fits = [(_without(req, t), t) for t in loc.markers]
            fits = [(f, t) for f, t in fits if f[1].found]
            if fits:
                (req, loc), _ = min(fits, key=lambda ft: math.inf if ft[0][1].rms_px is None else ft[0][1].rms_px)
                continue
        worst = _worst_marker(req, loc)
        req, loc = _without(req, worst)
    return loc


def _without(req: SolvePose, text: str) -> tuple[SolvePose, Localization]:
    req = req.model_copy(update={"observations": [o for o in req.observations if o.text != text]})
    return req, _solve(req)


def _worst_marker(req: SolvePose, loc: Localization) -> str:
    p = cast(Pose2D, loc.pose)  # a found localization's
    errs: dict[str, float] = {}
    for o in req.observations:
        v = observed_views([o], req.landmarks)
        if v:
            r = residuals(np.array([p.x, p.y, p.theta]), v)
            errs[o.text] = max(errs.get(o.text, 0.0), float(np.sqrt(np.mean(r ** 2))))
    return max(errs, key=errs.__getitem__) if errs else loc.markers[-1]


def _solve(req: SolvePose) -> Localization:
    loc = initial_pose(req)
    if not loc.found:
        return loc
    obs = [o for o in req.observations if o.text in req.landmarks]
    distinct = {o.text for o in obs}
    too_far = (len(distinct) == 1 and loc.method == "single"
               and min(o.distance_m for o in obs if o.text == loc.markers[0]) > SINGLE_MAX_M)
    p = cast(Pose2D, loc.pose)  # a found localization's
    starts = [(p.x, p.y, p.theta)]
    if loc.method == "single":  # both planar-ambiguity solutions of the code as starts
        starts += [(q.x, q.y, q.theta) for o in obs if o.text == loc.markers[0] for q in o.poses]
    views = observed_views(obs, req.landmarks)
    fit = refine(starts, views)
    far = Localization(found=False, markers=loc.markers, method="single-too-far")
    if fit is None:
        return far if too_far else loc
    (x, y, th), rms = fit
    moved = math.hypot(x - p.x, y - p.y)
    if rms > 4.0 or moved > 0.6:  # the fit did not converge to a consistent pose: keep the first estimate
        return far if too_far else loc
    std_m, std_rad = pose_std((x, y, th), views)
    if too_far:  # not a fix; its pose and spread still help a task whose estimate is far worse (the start)
        return Localization(found=False, pose=dict(x=x, y=y, theta=th), markers=loc.markers, method="single-too-far",
                            rms_px=rms, std_m=std_m, std_theta_rad=std_rad)
    return Localization(found=True, pose=dict(x=x, y=y, theta=th), markers=loc.markers, method=loc.method + "+fit",
                        rms_px=rms, std_m=std_m, std_theta_rad=std_rad)


def initial_pose(req: SolvePose) -> Localization:
    obs = [o for o in req.observations if o.text in req.landmarks]
    if not obs:
        return Localization(found=False)
    best: dict[str, Observation] = {}
    for o in obs:  # one observation per landmark: the nearest view
        if o.text not in best or o.distance_m < best[o.text].distance_m:
            best[o.text] = o
    obs = sorted(best.values(), key=lambda o: o.distance_m)
    if len(obs) >= 2:
        a = np.array([o.in_robot[:2] for o in obs])
        b = np.array([[req.landmarks[o.text].x, req.landmarks[o.text].y] for o in obs])
        if np.linalg.norm(b - b.mean(0), axis=1).max() > 0.5:  # landmarks far enough apart
            w = 1.0 / np.array([o.distance_m for o in obs]) ** 2
            x, y, th = rigid_fit(a, b, w)
            return Localization(found=True, pose=dict(x=x, y=y, theta=th), markers=[o.text for o in obs],
                                method="points")
    o = obs[0]  # nearest; codes too close together for a points fit still all enter the refinement
    pose = o.poses[0]
    prior = req.prior
    if prior is not None:  # the solution whose heading agrees with the current estimate
        pose = min(o.poses, key=lambda p: abs(math.remainder(p.theta - prior.theta, math.tau)))
    return Localization(found=True, pose=pose, markers=[x.text for x in obs], method="single")


class LandmarkCloud(CloudService):
    """A Cloud part serving the SDK's landmark localization (ontology.landmarks). Subclass it, with
    an `ontology` of your own for your own actions, or use it as it is."""

    ontology = ONTOLOGY

    async def observe(self, req: Observe) -> Observations:
        return await asyncio.to_thread(observe, req)

    async def solve_pose(self, req: SolvePose) -> Localization:
        return await asyncio.to_thread(solve_pose, req)
