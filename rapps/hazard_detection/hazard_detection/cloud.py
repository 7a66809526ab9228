"""Cloud Agent part: QR-marker global localization (paper 001 fig. 6) with the Platform's shared math.

A first estimate: with two or more distinct landmarks, from their centres only (a weighted 2-D rigid
fit of robot-frame to map positions): ranges and bearings of codes are far more accurate than a
single code's orientation; with one landmark, that code's full pose. Then the planar pose (x, y,
theta) is refined by minimizing the reprojection error of every corner of every code in every view of
the sweep (the camera height, roll and pitch are known from the robot's kinematics, so only three
unknowns remain: a single code's heading is no longer the ill-conditioned 6-DOF one)."""
import asyncio
import math

import cv2
import numpy as np
from scipy.optimize import least_squares

from rapps.sdk import CloudService
from rapps.sdk import vision as L

from .models import (ONTOLOGY, DoorViewList, DoorViews, DoorViewSpec, Localization, Observation, Observations,
                     Observe, SolvePose)
from .view import CameraModel, distinct, door_views


def observe(req: Observe) -> Observations:
    img = L.decode_image(req.image_b64)
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    K, dist = L.camera_matrix(req.camera)
    T_robot_cam = np.asarray(req.camera_to_robot, float)
    items = []
    for text, corners in L.detect_qr(img):
        lm = req.landmarks.get(text)
        if lm is None:
            continue
        refined = L.refine_corners(gray, corners).reshape(4, 2)
        solutions = code_poses(refined, lm.size_m, K, dist)
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


def rigid_fit(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> tuple[float, float, float]:
    """(x, y, theta) of the transform b = R(theta) a + t minimizing the weighted squared error."""
    w = w / w.sum()
    ca, cb = (w[:, None] * a).sum(0), (w[:, None] * b).sum(0)
    A, B = a - ca, b - cb
    H = (w[:, None, None] * A[:, :, None] * B[:, None, :]).sum(0)
    theta = math.atan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
    R = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    t = cb - R @ ca
    return float(t[0]), float(t[1]), theta


def _views(obs: list[Observation], landmarks) -> list[tuple]:
    """Per observation with corners: (world corners 4x3, measured 4x2, K, T_cam_robot)."""
    out = []
    for o in obs:
        if len(o.corners) != 4 or o.camera is None or len(o.camera_to_robot) != 4:
            continue
        lm = landmarks[o.text]
        T_world_code = L.landmark_transform(lm)
        pts = (T_world_code[:3, :3] @ L.code_corners_3d(lm.size_m).T).T + T_world_code[:3, 3]
        K, _ = L.camera_matrix(o.camera)
        out.append((pts, np.asarray(o.corners, float), K, L.invert(np.asarray(o.camera_to_robot, float))))
    return out


def _residuals(q: np.ndarray, views: list[tuple]) -> np.ndarray:
    x, y, th = q
    c, s = math.cos(th), math.sin(th)
    T_robot_world = L.invert(L.transform(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), [x, y, 0.0]))
    res = []
    for pts, uv, K, T_cam_robot in views:
        T = T_cam_robot @ T_robot_world
        pc = (T[:3, :3] @ pts.T).T + T[:3, 3]
        z = np.maximum(pc[:, 2], 1e-3)
        proj = np.stack([K[0, 0] * pc[:, 0] / z + K[0, 2], K[1, 1] * pc[:, 1] / z + K[1, 2]], 1)
        res.append((proj - uv).ravel())
    return np.concatenate(res)


PIXEL_NOISE = 0.5  # px, standard deviation of a refined corner (rendered codes, measured)


def pose_std(q: np.ndarray, views: list[tuple]) -> tuple[float, float]:
    """Standard deviations of the fitted position (m, along the worst direction) and heading (rad)
    from the corners' pixel noise: the Gauss-Newton covariance of the fit. Two codes close together
    or one far code leave the pose poorly fixed even when the residual is small."""
    r0 = _residuals(q, views)
    J = np.empty((len(r0), 3))
    for k, eps in enumerate((1e-5, 1e-5, 1e-6)):
        d = np.zeros(3)
        d[k] = eps
        J[:, k] = (_residuals(q + d, views) - r0) / eps
    try:
        cov = np.linalg.inv(J.T @ J) * PIXEL_NOISE ** 2
    except np.linalg.LinAlgError:
        return math.inf, math.inf
    return (float(math.sqrt(max(np.linalg.eigvalsh(cov[:2, :2]).max(), 0.0))),
            float(math.sqrt(max(cov[2, 2], 0.0))))


def refine(starts: list[tuple[float, float, float]], views: list[tuple]) -> tuple[tuple[float, float, float], float] | None:
    """Planar robot pose minimizing the corners' reprojection error, from the best of the start poses;
    (pose, rms px) or None without usable views."""
    if not views:
        return None
    best = None
    for q0 in starts:
        sol = least_squares(_residuals, np.asarray(q0, float), args=(views,), loss="soft_l1", f_scale=2.0,
                            x_scale=[0.1, 0.1, 0.02])
        rms = float(np.sqrt(np.mean(_residuals(sol.x, views) ** 2)))
        if best is None or rms < best[1]:
            best = ((float(sol.x[0]), float(sol.x[1]), math.remainder(float(sol.x[2]), math.tau)), rms)
    return best


SINGLE_MAX_M = 2.5  # one code farther than this fixes the pose too poorly (tens of cm): keep odometry
GOOD_RMS_PX = 2.0  # above this a multi-code fit drops its worst code and tries again


def solve_pose(req: SolvePose) -> Localization:
    loc = _solve(req)
    while (loc.found and loc.rms_px is not None and loc.rms_px > GOOD_RMS_PX and len(loc.markers) > 1):
        worst = _worst_marker(req, loc)  # one code disagrees (partly hidden, seen too obliquely)
        req = req.model_copy(update={"observations": [o for o in req.observations if o.text != worst]})
        loc = _solve(req)
    return loc


def _worst_marker(req: SolvePose, loc: Localization) -> str:
    p = loc.pose
    errs = {}
    for o in req.observations:
        v = _views([o], req.landmarks)
        if v:
            r = _residuals(np.array([p.x, p.y, p.theta]), v)
            errs[o.text] = max(errs.get(o.text, 0.0), float(np.sqrt(np.mean(r ** 2))))
    return max(errs, key=errs.get) if errs else loc.markers[-1]


def _solve(req: SolvePose) -> Localization:
    loc = initial_pose(req)
    if not loc.found:
        return loc
    obs = [o for o in req.observations if o.text in req.landmarks]
    distinct = {o.text for o in obs}
    if (len(distinct) == 1 and loc.method == "single"
            and min(o.distance_m for o in obs if o.text == loc.markers[0]) > SINGLE_MAX_M):
        return Localization(found=False, markers=loc.markers, method="single-too-far")
    p = loc.pose
    starts = [(p.x, p.y, p.theta)]
    if loc.method == "single":  # both planar-ambiguity solutions of the code as starts
        starts += [(q.x, q.y, q.theta) for o in obs if o.text == loc.markers[0] for q in o.poses]
    fit = refine(starts, _views(obs, req.landmarks))
    if fit is None:
        return loc
    (x, y, th), rms = fit
    moved = math.hypot(x - p.x, y - p.y)
    if rms > 4.0 or moved > 0.6:  # the fit did not converge to a consistent pose: keep the first estimate
        return loc
    std_m, std_rad = pose_std(np.array([x, y, th]), _views(obs, req.landmarks))
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
    if req.prior is not None:  # the solution whose heading agrees with the current estimate
        pose = min(o.poses, key=lambda p: abs(math.remainder(p.theta - req.prior.theta, math.tau)))
    return Localization(found=True, pose=pose, markers=[x.text for x in obs], method="single")


class LocalizationCloud(CloudService):
    ontology = ONTOLOGY

    async def observe(self, req: Observe) -> Observations:
        return await asyncio.to_thread(observe, req)

    async def solve_pose(self, req: SolvePose) -> Localization:
        return solve_pose(req)

    async def door_views(self, req: DoorViews) -> DoorViewList:
        return await asyncio.to_thread(views_for, req)


def views_for(req: DoorViews) -> DoorViewList:
    """The stands from which the image method is predicted right for every opening (view.py)."""
    k, c = req.camera.intrinsics, req.camera
    camera = CameraModel(k.fx, k.fy, k.cx, k.cy, c.width, c.height, c.z, c.ahead)
    views = door_views(req.door, req.robot_side, camera, req.rooms, req.doors, robot_radius=req.robot_radius_m,
                       room_rect=req.room.rect if req.room is not None else None,
                       open_threshold_deg=req.open_threshold_deg)
    return DoorViewList(views=[DoorViewSpec(x=v.x, y=v.y, theta=v.theta, look=list(v.look), margin=round(v.margin, 2),
                                            distance_m=v.distance_m, bearing_deg=v.bearing_deg)
                               for v in distinct(views)[:req.limit]])
