"""Virtual receptors: camera (TinyRenderer), ray-based range sensors (sonar, laser). The microphones
are in robots/microphones.py.

Camera/range methods run in the world's pybullet thread (call them through World.run / RobotAPI).
Camera optical frame: x right, y down, z forward; intrinsics match the rendering projection exactly
(square pixels, D = 0, OpenCV convention: pixel centres at integer coordinates). TinyRenderer samples
pixel (column i, row j) at OpenGL window coordinates (i, H - 1 - j), not at the pixel centres
(i + 0.5, H - 0.5 - j), so the principal point is (W/2, H/2 - 1), not (W/2 - 0.5, H/2 - 0.5)."""
from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from .pybullet_quiet import p

from .errors import InvalidArgument
from .lighting import room_light
from .failure_modes import CameraNoise, RangeNoise, camera_motion, noisy_ranges, reading_rng, seed_sequence
from .spec import CameraSpec, RangeSpec

if TYPE_CHECKING:
    from .body import Body

RESOLUTIONS = {"QQVGA": (160, 120), "QVGA": (320, 240), "VGA": (640, 480), "4VGA": (1280, 960)}
LIGHT = dict(lightDirection=[0.35, 0.25, 1.0], lightColor=[1, 1, 1], lightDistance=10.0,
             lightAmbientCoeff=0.55, lightDiffuseCoeff=0.5, lightSpecularCoeff=0.0, shadow=0)
# rotation from a camera link frame (x forward, y left, z up) to its optical frame (x right, y down, z fwd)
R_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def parse_resolution(res: str | tuple[int, int]) -> tuple[int, int]:
    if isinstance(res, tuple):
        return res
    key = res.strip().upper()
    if key in RESOLUTIONS:
        return RESOLUTIONS[key]
    m = re.fullmatch(r"(\d+)\s*[xX]\s*(\d+)", res.strip())
    if not m:
        raise InvalidArgument(f"bad resolution {res!r}: use 'WxH' or one of {', '.join(RESOLUTIONS)}")
    w, h = int(m.group(1)), int(m.group(2))
    if not (8 <= w <= 2048 and 8 <= h <= 2048):
        raise InvalidArgument(f"resolution {w}x{h} out of range 8..2048")
    return w, h


@dataclass(frozen=True)
class ImageParams:
    brightness: float = 0.0  # added after contrast, in [-1, 1] of full scale
    contrast: float = 1.0  # scales around mid-grey
    gain: float = 1.0
    exposure: float = 1.0  # relative exposure; lamps saturate, walls darken at low exposure
    auto_exposure: bool = False
    # the camera's failure modes at the moment of the capture (robots/failure_modes.py); defaults: ideal
    metering: str = "median"  # auto-exposure: "median" (ideal) or "centre" (centre-weighted mean, a real camera's)
    shot_variance: float = 0.0  # sensor noise variance per unit signal (full scale 1)
    read_std: float = 0.0  # sensor read noise, full scale 1
    noise_seed: tuple[int, ...] | None = None
    blur_rate: tuple[float, float] = (0.0, 0.0)  # rad/s the scene moves in the image (horizontal, vertical)
    exposure_time_s: float = 0.0  # exposure time at relative exposure 1 (motion blur)
    hfov_rad: float = 0.0


CAPTURE_DEFAULTS = dict(metering="median", shot_variance=0.0, read_std=0.0, noise_seed=None, blur_rate=(0.0, 0.0),
                        exposure_time_s=0.0, hfov_rad=0.0)
AE_TARGET = 0.45  # auto-exposure brings the metered brightness here
AE_RANGE = (0.25, 4.0)


def auto_exposure(radiance: np.ndarray, metering: str) -> float:
    """Relative exposure an auto-exposure picks for this scene."""
    if metering == "centre":  # centre-weighted mean of the (saturating) scene: a lit lamp darkens the rest
        h, w = radiance.shape[:2]
        import cv2
        grey = cv2.transform(np.ascontiguousarray(radiance, np.float32), _MEAN_RGB)  # the channels' mean
        np.minimum(grey, 2.0, out=grey)
        level = float(np.dot(grey.reshape(-1), _centre_weight(h, w)))
    else:
        level = float(np.median(radiance))
    return float(np.clip(AE_TARGET / max(level, 1e-3), *AE_RANGE))


_MEAN_RGB = np.full((1, 3), 1.0 / 3.0, np.float32)


@functools.lru_cache(maxsize=4)
def _centre_weight(h: int, w: int) -> np.ndarray:
    """The centre-weighted metering's weights (flattened, summing to 1), once per resolution."""
    yy, xx = np.mgrid[0:h, 0:w]
    weight = np.exp(-(((xx - w / 2) / (0.35 * w)) ** 2 + ((yy - h / 2) / (0.35 * h)) ** 2))
    return (weight / weight.sum()).astype(np.float32).reshape(-1)


NOISE_PAD = 64  # a frame's noise is a window of a field this much larger than the frame, at a seeded offset


@functools.lru_cache(maxsize=4)
def _noise_field(seed: tuple[int, ...], h: int, w: int, channels: int) -> np.ndarray:
    """Standard normal noise drawn once per camera and resolution (the frame's seed without its step)."""
    rng = np.random.default_rng(seed)
    return rng.standard_normal((h + NOISE_PAD, w + NOISE_PAD, channels), dtype=np.float32)


def sensor_noise(shape: tuple[int, ...], seed: tuple[int, ...] | None) -> np.ndarray:
    """Standard normal noise of one frame (a read-only view): a window of the camera's noise field at an
    offset and sign drawn from the frame's seed, so that the same step gives the same noise and
    frames of successive steps different noise, without drawing millions of normals a frame. Frames
    share values (shifted), which matters to nothing here that reads a frame on its own."""
    h, w = shape[:2]
    channels = shape[2] if len(shape) > 2 else 1
    if seed is None:  # unseeded: a fresh field
        return np.random.default_rng().standard_normal(shape, dtype=np.float32)
    field = _noise_field(tuple(seed[:-1]), h, w, channels)
    dy, dx, flip = np.random.default_rng(seed).integers(0, (NOISE_PAD, NOISE_PAD, 2))
    view = field[dy:dy + h, dx:dx + w]
    view = view[::-1, ::-1] if flip else view
    return view.reshape(shape)


def motion_blur(radiance: np.ndarray, length_px: float, angle: float) -> np.ndarray:
    """Linear motion blur of `length_px` along `angle` (rad, image x to y)."""
    import cv2
    size = int(math.ceil(length_px)) | 1
    kernel = np.zeros((size, size), np.float32)
    c = size // 2
    for t in np.linspace(-length_px / 2, length_px / 2, max(2, int(math.ceil(length_px)) * 2)):
        x, y = c + t * math.cos(angle), c + t * math.sin(angle)
        x0, y0 = int(math.floor(x)), int(math.floor(y))
        fx, fy = x - x0, y - y0
        for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            if 0 <= x0 + dx < size and 0 <= y0 + dy < size:
                kernel[y0 + dy, x0 + dx] += wgt
    kernel /= kernel.sum()
    return cv2.filter2D(radiance.astype(np.float32), -1, kernel, borderType=cv2.BORDER_REFLECT)


def apply_params(radiance: np.ndarray, params: ImageParams) -> np.ndarray:
    """radiance: float HxWx3 (1.0 = white wall fully lit) -> uint8 image: exposure (set or automatic),
    motion blur during the exposure, sensor noise, gain, contrast, brightness."""
    e = params.exposure
    if params.auto_exposure:
        e = auto_exposure(radiance, params.metering)
    rate = math.hypot(*params.blur_rate)
    if rate > 0 and params.exposure_time_s > 0 and params.hfov_rad > 0:
        f = (radiance.shape[1] / 2) / math.tan(params.hfov_rad / 2)
        length = f * rate * params.exposure_time_s * min(e, 1.0 / (30 * params.exposure_time_s))
        if length >= 0.5:
            radiance = motion_blur(radiance, length, math.atan2(params.blur_rate[1], params.blur_rate[0]))
    signal = np.multiply(radiance, e, dtype=np.float32)  # a new array: the steps below work in place
    if params.shot_variance or params.read_std:
        sigma = np.clip(signal, 0.0, 1.0)
        sigma *= params.shot_variance
        sigma += params.read_std ** 2
        np.sqrt(sigma, out=sigma)
        sigma *= sensor_noise(signal.shape, params.noise_seed)
        signal += sigma
    signal *= params.gain
    signal -= 0.5
    signal *= params.contrast
    signal += 0.5
    signal += params.brightness
    np.clip(signal, 0.0, 1.0, out=signal)
    signal *= 255.0
    signal += 0.5
    return signal.astype(np.uint8)


FRAME_BYTES = 180_000  # an encoded frame's budget: base64 of it (240 000 chars) fits one message (agents/base.py MAX_BODY)
JPEG_QUALITIES = (95, 90, 85, 80, 70, 60, 50)


def encode_frame(rgb: np.ndarray, lossless: bool = True) -> tuple[str, bytes]:
    """(encoding, bytes) of an RGB frame to send: PNG for a noise-free render (exact pixels); a noisy
    sensor's frame does not compress losslessly (1.8 MB for 1280x960), so it is sent as a real camera
    streams it: JPEG, at the best quality that fits FRAME_BYTES."""
    import cv2
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    if lossless:
        ok, buf = cv2.imencode(".png", bgr)
        return "png", buf.tobytes()
    for q in JPEG_QUALITIES:
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, q])
        if len(buf) <= FRAME_BYTES:
            break
    return "jpeg", buf.tobytes()


def render_radiance(cid: int, width: int, height: int, view, proj,
                    emissive: dict[int, tuple[float, float, float]], light_scale: float = 1.0) -> np.ndarray:
    """Render with TinyRenderer in client `cid`: float HxWx3 radiance (1 = a lit white wall), the
    bodies in `emissive` (uid -> radiance: lit lamp shades, windows by day; robots/lighting.py) set to
    theirs; `light_scale`: the room's ambient and diffuse light (lighting.room_light). Shared by the
    in-process camera and the render process (robots/render_process.py), so both give the same pixels
    for the same scene state."""
    flags = 0 if emissive else p.ER_NO_SEGMENTATION_MASK
    light = LIGHT if light_scale == 1.0 else {**LIGHT, "lightAmbientCoeff": LIGHT["lightAmbientCoeff"] * light_scale,
                                              "lightDiffuseCoeff": LIGHT["lightDiffuseCoeff"] * light_scale}
    out = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER, flags=flags,
                           physicsClientId=cid, **light)
    rgb = np.asarray(out[2], dtype=np.float32).reshape(height, width, 4)[:, :, :3] / 255.0
    if emissive:
        seg = np.asarray(out[4]).reshape(height, width)
        for uid, radiance in emissive.items():
            rgb[seg == uid] = np.asarray(radiance, np.float32)
    return rgb


class Camera:
    def __init__(self, robot: "Body", spec: CameraSpec):
        self.robot, self.spec, self.name = robot, spec, spec.name
        self.settings = ImageParams()  # what the user set (set_params)
        self.noise: CameraNoise | None = None  # failure modes (robots/failure_modes.py), None: ideal

    def set_noise(self, noise: CameraNoise | None) -> None:
        """The camera's failure modes (None: ideal); auto-exposure starts as the real camera's does."""
        self.noise = noise
        self.settings = replace(self.settings, auto_exposure=bool(noise is not None and noise.auto_exposure))

    @property
    def params(self) -> ImageParams:
        """The image parameters of a capture now: the settings plus, with failure modes, the sensor noise
        (seeded by the simulation step), auto-exposure metering and the motion blur of this moment."""
        n = self.noise
        if n is None:
            return self.settings
        r = self.robot
        step = int(round(r.world.clock.time / r.world.clock.step))
        return replace(self.settings, metering="centre", shot_variance=n.shot_variance, read_std=n.read_std,
                       noise_seed=tuple(seed_sequence(r.world.plan.seed, "camera", r.name, self.name)) + (step,),
                       blur_rate=camera_motion(r, n.scene_depth_m, self.spec.link), exposure_time_s=n.exposure_time_s,
                       hfov_rad=math.radians(self.spec.hfov_deg))

    @params.setter
    def params(self, value: ImageParams) -> None:
        self.settings = replace(value, **CAPTURE_DEFAULTS)  # the user's part; the failure modes are added per capture

    # ---- geometry (pure, any thread)
    def fov(self, width: int, height: int) -> tuple[float, float]:
        h = math.radians(self.spec.hfov_deg)
        return h, 2 * math.atan(math.tan(h / 2) * height / width)

    def intrinsics(self, width: int, height: int) -> np.ndarray:
        hfov, _ = self.fov(width, height)
        f = (width / 2) / math.tan(hfov / 2)
        # TinyRenderer's sampling points (see the module docstring), measured on rendered edges
        return np.array([[f, 0, width / 2], [0, f, height / 2 - 1.0], [0, 0, 1.0]])

    def set_params(self, **kw) -> ImageParams:
        """Change the settings given (None: unchanged). Setting the exposure switches auto-exposure off
        unless auto_exposure is given too, as on a real camera."""
        kw = {k: v for k, v in kw.items() if v is not None}
        if "exposure" in kw and "auto_exposure" not in kw:
            kw["auto_exposure"] = False
        self.settings = replace(self.settings, **kw)
        return self.settings

    # ---- pybullet thread
    def link_pose(self, nominal: bool = False) -> np.ndarray:
        """4x4 world pose of the camera link as it is: the robot's kinematics, and a walking NAO's torso
        roll and bob (Robot.body_sway) unless `nominal` (what the robot's kinematics report: get_transform)."""
        T = self.robot.link_pose(self.spec.link)
        sway = None if nominal else self.robot.body_sway()
        return T if sway is None else sway @ T

    def optical_pose(self, nominal: bool = False) -> np.ndarray:
        """4x4 world pose of the optical frame (x right, y down, z forward), as it is or `nominal` (link_pose)."""
        T = self.link_pose(nominal)
        T[:3, :3] = T[:3, :3] @ R_LINK_OPTICAL
        return T

    def view_projection(self, width: int, height: int) -> tuple[list[float], list[float]]:
        """OpenGL view and projection matrices (16 floats each) of this camera's current pose."""
        return camera_matrices(self.link_pose(), self.spec, width, height, self.robot.world.cid)

    def render_radiance(self, width: int, height: int) -> np.ndarray:
        view, proj = self.view_projection(width, height)
        world = self.robot.world
        return render_radiance(world.cid, width, height, view, proj, world.emissive,
                               room_light(world.plan.sky) * world.light_scale)

    def capture(self, width: int = 320, height: int = 240) -> np.ndarray:
        """RGB uint8 image (HxWx3) with the current image parameters applied."""
        return apply_params(self.render_radiance(width, height), self.params)


def camera_matrices(T: np.ndarray, spec, width: int, height: int, cid: int) -> tuple[list[float], list[float]]:
    """OpenGL view and projection matrices (16 floats each) of a camera (its spec: hfov_deg, near, far)
    whose link frame is T (4x4: x forward, z up); bench/mainjob.py's floor renders with the same."""
    eye, fwd, up = T[:3, 3], T[:3, 0], T[:3, 2]
    vfov = 2 * math.atan(math.tan(math.radians(spec.hfov_deg) / 2) * height / width)
    view = p.computeViewMatrix(eye.tolist(), (eye + fwd).tolist(), up.tolist(), physicsClientId=cid)
    proj = p.computeProjectionMatrixFOV(math.degrees(vfov), width / height, spec.near, spec.far, physicsClientId=cid)
    return list(view), list(proj)


class RangeSensor:
    """A fan of rays from a robot link (sonar cone: reports the minimum; laser: every ray)."""

    def __init__(self, robot: "Body", spec: RangeSpec):
        self.robot, self.spec, self.name = robot, spec, spec.name
        self.noise: RangeNoise | None = None  # failure modes (robots/failure_modes.py), None: exact

    def angles(self) -> np.ndarray:
        return np.linspace(self.spec.angle_min, self.spec.angle_max, self.spec.rays)

    def scan(self, noisy: bool = True) -> np.ndarray:
        """Ranges (m) of every ray, range_max when nothing is hit (with the sensor's noise unless
        `noisy` is False). pybullet thread."""
        s = self.spec
        T = self.robot.link_pose(s.link)
        a = self.angles()
        local = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)
        dirs = local @ T[:3, :3].T
        origin = T[:3, 3]
        starts = np.repeat(origin[None], len(a), 0)
        ends = origin + dirs * s.range_max
        with self.robot.probe_hidden():
            hits = p.rayTestBatch(starts.tolist(), ends.tolist(), physicsClientId=self.robot.world.cid)
        frac = np.array([h[2] if h[0] >= 0 else 1.0 for h in hits])
        ranges = np.clip(frac * s.range_max, s.range_min, s.range_max)
        return self._noisy(ranges) if noisy else ranges

    def _noisy(self, ranges: np.ndarray) -> np.ndarray:
        if self.noise is None:
            return ranges
        s = self.spec
        return noisy_ranges(ranges, self.noise, reading_rng(self.robot, self.name), s.range_min, s.range_max)

    def read(self) -> float:
        """The nearest echo of the cone (one noisy reading, as a sonar gives)."""
        return float(self._noisy(np.array([self.scan(noisy=False).min()]))[0])
