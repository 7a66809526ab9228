"""Issue #5: QR pose error < 2 cm at 1.5 m on images RENDERED by PyBullet (TinyRenderer) of the house's QR
panels, not only on the synthetic warps of test_localization.py.

One 'small' world per module; an Elektron and a NAO are teleported (base pose + odometry estimate) to view
poses ~1.5 m from a panel (head-on, oblique up to 35 deg, the code off the image centre), look at a point,
and capture at the hazard RApp's localization resolution (800x600) and at 640x480. qr_detection gets the
intrinsics from get_camera_info and the landmark's code size.

Ground truth (code -> camera): T_world_cam from get_transform(chain="camera", space="global") (checked
against the OpenGL view matrix the renderer used), T_world_code from the pose of the textured quad body in
the pybullet scene (the printed surface: 1.05 cm in front of the map's landmark point, see _code_pose).

    python tests/services/test_qr_render.py      # prints the error table
"""
from __future__ import annotations

import asyncio
import math

import cv2
import numpy as np
import pytest

from agents.services import localization as L
from agents.services.images import decode_image
from ontology.services.common import CameraIntrinsics
from ontology.services.localization import QRDetect

DIST = 1.5  # m, camera centre to code centre
RESOLUTIONS = ("800x600", "640x480")  # rapps/hazard_detection/manifest.yaml localize_resolution, and VGA
ROBOTS = ("elektron", "nao")
PARK = {"elektron": (5.0, 3.0, 0.0), "nao": (5.0, 1.0, 0.0)}  # bedroom, behind the inner wall
# (landmark, view angle from the panel normal in deg (+ = toward the viewer's left of the panel),
#  look-at offset from the code centre along the panel (+ = viewer's right) and up, m)
VIEWS = {
    "s1_head_on": ("qr_s1", 0, 0.0, 0.0),
    "s1_head_on_off_centre": ("qr_s1", 0, 0.35, -0.15),
    "s1_20deg_off_centre": ("qr_s1", 20, -0.3, 0.0),
    "s1_35deg": ("qr_s1", 35, 0.0, 0.0),
    "s1_-35deg_off_centre": ("qr_s1", -35, 0.25, 0.15),
    "s2_30deg": ("qr_s2", -30, 0.0, 0.0),
}
CASES = [(k, r, v) for k in ROBOTS for r in RESOLUTIONS for v in VIEWS]
GL_TO_OPTICAL = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenGL camera (x right, y up, z back) -> optical


def _code_pose(world, lm) -> np.ndarray:
    """World pose of the printed code (code frame of localization.py: x right, y up, z out of the face),
    read from the scene: the textured quad body nearest to the landmark. Its local frame (robots/world.py
    _landmark_body) has x = panel normal, y = viewer's right, z = up; the symbol (without quiet zone) is
    centred on it with side lm.size."""
    import pybullet as p

    def find():
        best = None
        for i in range(p.getNumBodies(physicsClientId=world.cid)):
            uid = p.getBodyUniqueId(i, physicsClientId=world.cid)
            shapes = p.getVisualShapeData(uid, physicsClientId=world.cid)
            if len(shapes) != 1 or shapes[0][2] != p.GEOM_MESH:
                continue
            pos, orn = p.getBasePositionAndOrientation(uid, physicsClientId=world.cid)
            d = math.dist(pos, (lm.x, lm.y, lm.z))
            if d < 0.05 and (best is None or d < best[0]):
                best = (d, pos, orn)
        assert best is not None, f"no QR quad found for {lm.id}"
        return best

    _, pos, orn = world.run_sync(find)
    R_quad = np.array(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
    quad_to_code = np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]])  # code x = quad y, y = quad z, z = quad x
    return L.transform(R_quad @ quad_to_code, pos)


def _teleport(world, robot, pose) -> None:
    def go():
        robot.set_base_pose(*pose)
        robot.odometry.set(pose)  # get_transform(space="global") and look_at_point use the estimate

    world.run_sync(go)


async def _shoot(world, robot, api, lm, T_world_code, view, resolution):
    from ontology.robot import CaptureImage, GetCameraInfo, GetTransform, LookAtPoint

    _, ang, lat, up = view
    n = T_world_code[:2, 2]  # panel normal (into the room)
    left = -T_world_code[:2, 0]  # code x is the viewer's right
    a = math.radians(ang)
    d = n * math.cos(a) + left * math.sin(a)  # code centre -> camera, horizontal
    centre = T_world_code[:3, 3]
    look = centre + np.r_[T_world_code[:2, 0] * lat, up]
    base = centre[:2] + DIST * d
    th = math.atan2(-d[1], -d[0])
    for _ in range(4):  # move the base until the camera centre is DIST from the code centre
        _teleport(world, robot, (float(base[0]), float(base[1]), th))
        await api.look_at_point(LookAtPoint(x=float(look[0]), y=float(look[1]), z=float(look[2])))
        T_cam = np.asarray((await api.get_transform(GetTransform(chain="camera", space="global"))).matrix)
        err = float(np.linalg.norm(T_cam[:3, 3] - centre)) - DIST
        if abs(err) < 0.005:
            break
        base = base - d * err
    w, h = map(int, resolution.split("x"))
    cam = robot.cameras[robot.spec.look_camera]
    view_m, _ = world.run_sync(cam.view_projection, w, h)
    img = await api.capture_image(CaptureImage(resolution=resolution))
    info = await api.get_camera_info(GetCameraInfo(resolution=resolution))
    return {"image": img.data_b64, "K": np.asarray(info.K), "T_world_cam": T_cam,
            "T_world_cam_render": np.linalg.inv(np.asarray(view_m).reshape(4, 4).T) @ GL_TO_OPTICAL,
            "T_world_code": T_world_code, "T_world_code_map": L.landmark_transform(lm), "lm": lm}


def measure() -> dict:
    robots = pytest.importorskip("robots")

    async def run():
        world = robots.World.from_file("small", seed=1)
        try:
            lms = {m.id: m for m in world.landmarks}
            codes = {k: _code_pose(world, m) for k, m in lms.items()}
            with robots.failure_modes.ideal_robots():  # the render's geometry, without camera noise
                bots = {k: world.add_robot(k, pose=PARK[k]) for k in ROBOTS}
            apis = {k: robots.RobotAPI(b) for k, b in bots.items()}
            out = {}
            for kind in ROBOTS:
                for view_id, view in VIEWS.items():
                    for res in RESOLUTIONS:
                        lm = lms[view[0]]
                        out[kind, res, view_id] = await _shoot(world, bots[kind], apis[kind], lm, codes[lm.id],
                                                               view, res)
                _teleport(world, bots[kind], PARK[kind])
            return out
        finally:
            world.close()

    return asyncio.run(run())


@pytest.fixture(scope="module")
def renders():
    return measure()


@pytest.fixture(scope="module")
def results(renders, tmp_path_factory):
    """qr_detection on every render, once per module."""
    from agents.services.context import ServiceContext, ServiceState

    ctx = ServiceContext(user="alice", state=ServiceState(work_dir=tmp_path_factory.mktemp("qr_render")))
    return {key: evaluate(r, ctx) for key, r in renders.items()}


def evaluate(r, ctx) -> dict:
    K, lm = r["K"], r["lm"]
    cam = CameraIntrinsics(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])
    out = L.qr_detection(QRDetect(image_b64=r["image"], camera=cam, code_size_m=lm.size), ctx)
    codes = [c for c in out.codes if c.text == lm.text]
    truth = L.invert(r["T_world_cam"]) @ r["T_world_code"]
    res = {"texts": [c.text for c in out.codes], "truth": truth, "found": bool(codes)}
    if codes:
        T = np.asarray(codes[0].pose_in_camera)
        res["T"] = T
        res["t_err"] = float(np.linalg.norm(T[:3, 3] - truth[:3, 3]))
        res["t_err_vec"] = T[:3, 3] - truth[:3, 3]
        res["rot_err_deg"] = math.degrees(math.acos(np.clip((np.trace(T[:3, :3].T @ truth[:3, :3]) - 1) / 2, -1, 1)))
        # image-space check of the intrinsics/extrinsics: ground-truth corners projected with K
        pc = (truth @ np.c_[L.code_corners_3d(lm.size), np.ones(4)].T)[:3]
        proj = ((K @ pc)[:2] / pc[2]).T
        gray = cv2.cvtColor(decode_image(r["image"]), cv2.COLOR_BGR2GRAY)
        res["proj"] = proj
        res["detected"] = np.asarray(codes[0].corners)
        res["refined"] = L.refine_corners(gray, res["detected"])
        # pose against the map's landmark point instead of the printed surface (for the record)
        truth_map = L.invert(r["T_world_cam"]) @ r["T_world_code_map"]
        res["t_err_map"] = float(np.linalg.norm(T[:3, 3] - truth_map[:3, 3]))
    return res


def test_ground_truth_frames(renders):
    """get_transform("camera", "global") is the optical frame (x right, y down, z forward) of the camera the
    renderer used, the camera is DIST from the code centre, and the printed surface is the map's landmark
    pose moved along the normal only (same orientation)."""
    for key, r in renders.items():
        assert np.allclose(r["T_world_cam"], r["T_world_cam_render"], atol=1e-6), key
        assert abs(np.linalg.norm(r["T_world_cam"][:3, 3] - r["T_world_code"][:3, 3]) - DIST) < 0.01, key
        assert np.allclose(r["T_world_code"][:3, :3], r["T_world_code_map"][:3, :3], atol=1e-6), key
        off = r["T_world_code"][:3, 3] - r["T_world_code_map"][:3, 3]
        assert np.allclose(np.cross(off, r["T_world_code"][:3, 2]), 0, atol=1e-6), key


@pytest.mark.parametrize("kind,res,view", CASES)
def test_qr_pose_error_below_2cm_at_1_5m_on_render(renders, results, kind, res, view):
    e = results[kind, res, view]
    assert e["found"], f"{renders[kind, res, view]['lm'].text} not decoded (got {e['texts']})"
    assert abs(e["truth"][2, 3] - DIST) < 0.3  # really ~1.5 m in front of the camera
    assert e["t_err"] < 0.02, e["t_err_vec"]
    assert e["rot_err_deg"] < 5.0
    # frame/ordering sanity: the corners are the projected ground-truth corners in the same order (TL, TR, BR,
    # BL), within a module (~4 px for the NAO at 640x480); a mirrored frame or a wrong order is off by ~100 px
    assert np.abs(e["detected"] - e["proj"]).max() < 3.0
    assert np.abs(e["refined"] - e["proj"]).max() < 3.0


@pytest.mark.parametrize("kind,res", [(k, r) for k in ROBOTS for r in RESOLUTIONS])
def test_intrinsics_match_render_without_offset(results, kind, res):
    """get_camera_info's principal point matches TinyRenderer's pixel sampling: refined corners show no
    common shift against the ground-truth projection (a half-pixel principal point error shows as ~0.7 px)."""
    diffs = []
    for view in VIEWS:
        e = results[kind, res, view]
        assert e["found"]
        diffs.append(e["refined"] - e["proj"])
    mean = np.concatenate(diffs).mean(axis=0)
    assert np.hypot(*mean) < 0.2, mean


if __name__ == "__main__":
    import tempfile

    from agents.services.context import ServiceContext, ServiceState

    c = ServiceContext(user="t", state=ServiceState(work_dir=tempfile.mkdtemp()))
    rs = measure()
    print(f"{'robot':8s} {'res':7s} {'view':24s} {'depth':>5s} {'t_err cm':>8s} {'(x, y, z) cm':>22s} {'rot deg':>7s} "
          f"{'map cm':>6s} {'corner px':>9s} {'mean shift px':>14s}")
    for (kind, res, view), r in rs.items():
        e = evaluate(r, c)
        if not e["found"]:
            print(kind, res, view, "NOT FOUND", e["texts"])
            continue
        v = e["t_err_vec"] * 100
        sh = (e["refined"] - e["proj"]).mean(0)
        print(f"{kind:8s} {res:7s} {view:24s} {e['truth'][2, 3]:5.2f} {e['t_err'] * 100:8.2f} "
              f"({v[0]:6.2f},{v[1]:6.2f},{v[2]:6.2f}) {e['rot_err_deg']:7.2f} {e['t_err_map'] * 100:6.2f} "
              f"{np.abs(e['refined'] - e['proj']).max():9.2f} ({sh[0]:5.2f},{sh[1]:5.2f})")
