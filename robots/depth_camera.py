"""A depth camera (the Elektron's Kinects): TinyRenderer's depth buffer turned into metres along the optical
axis, with a Kinect v1's noise (structured light, 7.5 cm baseline, disparity in 1/8 pixel steps).

Depth from the buffer d (0..1) of a perspective projection with clipping planes n, f: z = f n / (f - (f - n) d).
The noise model, in this order:
  - axial noise, growing with range and with the surface's obliquity (Nguyen, Izadi, Lovell 2012, fitted on
    a Kinect v1): sigma(z, a) = 0.0012 + 0.0019 (z - 0.4)^2 + 0.0001 / sqrt(z) * a^2 / (pi/2 - a)^2 m, a the
    angle between the ray and the surface normal (the normals come from the rendered depth's gradient);
  - disparity quantization: the sensor measures disparity f*b/z at its native 640 px width in 1/8 px steps,
    so depth comes in steps of z^2 / (8 f b): 3 mm at 1 m, 4.5 cm at 4 m;
  - missing returns (0): nearer than range_min or farther than range_max (the projector's pattern too
    faint), and on oblique surfaces: never below OBLIQUE_FROM, always above OBLIQUE_ALL, linearly between.
Simplified away: the shadow band beside near objects (the projector sits 7.5 cm beside the camera), dark or
specular materials that return nothing, lateral smearing at edges, interference of two Kinects, sunlight.
The noise is seeded by the simulation step, as the cameras' (robots/failure_modes.py); a robot without
failure modes (Robot.set_failure_modes(None)) has an ideal depth camera: exact depth, still range-limited.

Functions that render run in the world's pybullet thread or in a render process (robots/render_process.py
calls DepthParams.render_depth), so the noise is computed outside the Core's process too.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .depth_png import decode_depth, encode_depth  # noqa: F401 - the depth image's encoding, beside its camera
from .failure_modes import seed_sequence
from .pybullet_quiet import p
from .receptors import R_LINK_OPTICAL, Camera
from .spec import DepthCameraSpec

if TYPE_CHECKING:
    from .body import Body

BASELINE_M = 0.075  # Kinect v1: projector to IR camera
NATIVE_F_PX = 580.0  # its IR camera's focal length at 640 px width, where disparity is measured
DISPARITY_STEP_PX = 1 / 8
OBLIQUE_FROM, OBLIQUE_ALL = math.radians(65), math.radians(80)


def linear_depth(buffer: np.ndarray, near: float, far: float) -> np.ndarray:
    """Metres along the optical axis from an OpenGL depth buffer (0..1) of clipping planes near, far."""
    return (far * near / (far - (far - near) * buffer.astype(np.float64))).astype(np.float32)


def incidence(z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Angle (rad) between each pixel's ray and the surface normal there, from the depth's gradient."""
    h, w = z.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    pts = rays * z[..., None]
    normal = np.cross(np.gradient(pts, axis=1), np.gradient(pts, axis=0))
    cos = np.abs((normal * rays).sum(-1)) / (np.linalg.norm(normal, axis=-1) * np.linalg.norm(rays, axis=-1) + 1e-12)
    return np.arccos(np.clip(cos, 0.0, 1.0))


def axial_sigma(z: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Kinect v1 depth noise (m, 1 sigma) at depth z and incidence angle (Nguyen et al. 2012)."""
    a = np.minimum(angle, math.pi / 2 - 0.05)
    return 0.0012 + 0.0019 * (z - 0.4) ** 2 + 0.0001 / np.sqrt(np.maximum(z, 0.1)) * a ** 2 / (math.pi / 2 - a) ** 2


def quantize(z: np.ndarray) -> np.ndarray:
    """Depth as the sensor's disparity steps give it (measured at 640 px whatever the image's width)."""
    fb = NATIVE_F_PX * BASELINE_M
    d = np.round(fb / np.maximum(z, 1e-3) / DISPARITY_STEP_PX) * DISPARITY_STEP_PX
    return np.where(d > 0, fb / np.maximum(d, DISPARITY_STEP_PX), 0.0)


def kinect(z: np.ndarray, K: np.ndarray, range_min: float, range_max: float,
           rng: np.random.Generator | None) -> np.ndarray:
    """The sensor's depth image (float32 m, 0 = no return) from the true depth `z`; `rng` None: ideal."""
    out = z.astype(np.float64)
    if rng is not None:
        angle = incidence(z, K)
        out = out + axial_sigma(out, angle) * rng.standard_normal(z.shape)
        out = quantize(out)
        p_missing = np.clip((angle - OBLIQUE_FROM) / (OBLIQUE_ALL - OBLIQUE_FROM), 0.0, 1.0)
        out[rng.random(z.shape) < p_missing] = 0.0
    out[(z < range_min) | (z > range_max)] = 0.0
    return out.astype(np.float32)


def intrinsics(hfov_deg: float, width: int, height: int) -> np.ndarray:
    """Pinhole K of a render (TinyRenderer's sampling points, as robots/receptors.Camera.intrinsics)."""
    f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    return np.array([[f, 0, width / 2], [0, f, height / 2 - 1.0], [0, 0, 1.0]])


@dataclass(frozen=True)
class DepthParams:
    """What a render of a depth image needs besides the scene (pickled to a render process)."""

    hfov_deg: float
    near: float
    far: float
    range_min: float
    range_max: float
    noise_seed: tuple[int, ...] | None  # None: an ideal sensor

    def render_depth(self, cid: int, width: int, height: int, view, proj) -> np.ndarray:
        """Render in client `cid` and apply the sensor model: float32 HxW metres, 0 = no return."""
        out = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER,
                               flags=p.ER_NO_SEGMENTATION_MASK, physicsClientId=cid)
        z = linear_depth(np.asarray(out[3], np.float32).reshape(height, width), self.near, self.far)
        rng = None if self.noise_seed is None else np.random.default_rng(self.noise_seed)
        return kinect(z, intrinsics(self.hfov_deg, width, height), self.range_min, self.range_max, rng)


class DepthCamera:
    """A robot's depth camera; World.capture renders it (duck-typed as a robots.receptors.Camera)."""

    def __init__(self, robot: "Body", spec: DepthCameraSpec):
        self.robot, self.spec, self.name = robot, spec, spec.name
        self.noisy = True
        c, s = math.cos(math.radians(spec.pitch_deg)), math.sin(math.radians(spec.pitch_deg))
        self._mount = np.eye(4)  # link frame -> the sensor's frame (x forward, pitched down, z up)
        self._mount[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
        self._mount[:3, 3] = spec.xyz

    def set_noise(self, noisy: bool) -> None:
        self.noisy = noisy

    def intrinsics(self, width: int, height: int) -> np.ndarray:
        return intrinsics(self.spec.hfov_deg, width, height)

    @property
    def params(self) -> DepthParams:
        s, r = self.spec, self.robot
        seed = None
        if self.noisy:
            step = int(round(r.world.clock.time / r.world.clock.step))
            seed = tuple(seed_sequence(r.world.plan.seed, "depth", r.name, self.name)) + (step,)
        return DepthParams(s.hfov_deg, s.near, s.far, s.range_min, s.range_max, seed)

    # ---- pybullet thread
    def link_pose(self) -> np.ndarray:
        return self.robot.link_pose(self.spec.link) @ self._mount

    def optical_pose(self) -> np.ndarray:
        """4x4 world pose of the optical frame (x right, y down, z forward)."""
        T = self.link_pose()
        T[:3, :3] = T[:3, :3] @ R_LINK_OPTICAL
        return T

    # the colour camera's geometry, on this camera's pose, field of view and clipping planes
    fov = Camera.fov
    view_projection = Camera.view_projection

    def capture(self, width: int, height: int) -> np.ndarray:
        """The depth image rendered in this thread (World's inline rendering)."""
        view, proj = self.view_projection(width, height)
        return self.params.render_depth(self.robot.world.cid, width, height, view, proj)
