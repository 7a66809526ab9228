"""Virtual receptors: camera (TinyRenderer), ray-based range sensors (sonar, laser), microphone.

Camera/range methods run in the world's pybullet thread (call them through World.run / RobotAPI).
Camera optical frame: x right, y down, z forward; intrinsics match the rendering projection exactly
(square pixels, D = 0, OpenCV convention: pixel centres at integer coordinates). TinyRenderer samples
pixel (column i, row j) at OpenGL window coordinates (i, H - 1 - j), not at the pixel centres
(i + 0.5, H - 0.5 - j), so the principal point is (W/2, H/2 - 1), not (W/2 - 0.5, H/2 - 0.5)."""
from __future__ import annotations

import asyncio
import math
import re
import threading
from collections import deque
from dataclasses import dataclass, replace
from functools import partial
from typing import TYPE_CHECKING

import numpy as np
import pybullet as p

from .denoise import BandSpectra
from .errors import InvalidArgument
from .failure_modes import CameraNoise, RangeNoise, camera_motion, noisy_ranges, reading_rng, seed_sequence
from .spec import CameraSpec, RangeSpec

if TYPE_CHECKING:
    from .robot import Robot
    from .sound import HouseSound

RESOLUTIONS = {"QQVGA": (160, 120), "QVGA": (320, 240), "VGA": (640, 480), "4VGA": (1280, 960)}
LAMP_RADIANCE = 4.0  # lit lamp pixels are this many times brighter than a white wall
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
        yy, xx = np.mgrid[0:h, 0:w]
        weight = np.exp(-(((xx - w / 2) / (0.35 * w)) ** 2 + ((yy - h / 2) / (0.35 * h)) ** 2))
        level = float((np.minimum(radiance.mean(axis=2), 2.0) * weight).sum() / weight.sum())
    else:
        level = float(np.median(radiance))
    return float(np.clip(AE_TARGET / max(level, 1e-3), *AE_RANGE))


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
    signal = radiance * e
    if params.shot_variance or params.read_std:
        rng = np.random.default_rng(params.noise_seed)
        sigma = np.sqrt(params.shot_variance * np.clip(signal, 0.0, 1.0) + params.read_std ** 2)
        signal = signal + sigma * rng.standard_normal(signal.shape, dtype=np.float32)
    img = (signal * params.gain - 0.5) * params.contrast + 0.5 + params.brightness
    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


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


def pose_matrix(pos, quat) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.array(p.getMatrixFromQuaternion(quat)).reshape(3, 3)
    T[:3, 3] = pos
    return T


def render_radiance(cid: int, width: int, height: int, view, proj,
                    emissive: dict[int, tuple[float, float, float]]) -> np.ndarray:
    """Render with TinyRenderer in client `cid`: float HxWx3 radiance, lit lamp shades (body uid -> colour in
    `emissive`) replaced by LAMP_RADIANCE times their colour. Shared by the in-process camera and the
    render process (robots/render_process.py), so both give the same pixels for the same scene state."""
    flags = 0 if emissive else p.ER_NO_SEGMENTATION_MASK
    out = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER, flags=flags,
                           physicsClientId=cid, **LIGHT)
    rgb = np.asarray(out[2], dtype=np.float32).reshape(height, width, 4)[:, :, :3] / 255.0
    if emissive:
        seg = np.asarray(out[4]).reshape(height, width)
        for uid, color in emissive.items():
            rgb[seg == uid] = np.asarray(color, np.float32) * LAMP_RADIANCE
    return rgb


class Camera:
    def __init__(self, robot: "Robot", spec: CameraSpec):
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
                       blur_rate=camera_motion(r, n.scene_depth_m), exposure_time_s=n.exposure_time_s,
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
    def link_pose(self) -> np.ndarray:
        return self.robot.link_pose(self.spec.link)

    def optical_pose(self) -> np.ndarray:
        """4x4 world pose of the optical frame (x right, y down, z forward)."""
        T = self.link_pose()
        T[:3, :3] = T[:3, :3] @ R_LINK_OPTICAL
        return T

    def view_projection(self, width: int, height: int) -> tuple[list[float], list[float]]:
        """OpenGL view and projection matrices (16 floats each) of this camera's current pose."""
        T = self.link_pose()
        eye, fwd, up = T[:3, 3], T[:3, 0], T[:3, 2]
        _, vfov = self.fov(width, height)
        cid = self.robot.world.cid
        view = p.computeViewMatrix(eye.tolist(), (eye + fwd).tolist(), up.tolist(), physicsClientId=cid)
        proj = p.computeProjectionMatrixFOV(math.degrees(vfov), width / height, self.spec.near, self.spec.far,
                                            physicsClientId=cid)
        return list(view), list(proj)

    def render_radiance(self, width: int, height: int) -> np.ndarray:
        view, proj = self.view_projection(width, height)
        return render_radiance(self.robot.world.cid, width, height, view, proj, self.robot.world.emissive_colors)

    def capture(self, width: int = 320, height: int = 240) -> np.ndarray:
        """RGB uint8 image (HxWx3) with the current image parameters applied."""
        return apply_params(self.render_radiance(width, height), self.params)


class RangeSensor:
    """A fan of rays from a robot link (sonar cone: reports the minimum; laser: every ray)."""

    def __init__(self, robot: "Robot", spec: RangeSpec):
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


class Microphone:
    """Hears text: ``hear(text)`` is what a user or scenario says (thread-safe);
    ``spot(words, timeout)`` waits (wall clock) for the first utterance containing one of the words;
    ``listen(timeout)`` returns the next utterance, whatever it is."""

    def __init__(self):
        self._heard: deque[str] = deque()
        self._lock = threading.Lock()
        self._waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = []
        self.log: list[str] = []

    def hear(self, text: str) -> None:
        with self._lock:
            self._heard.append(text)
            self.log.append(text)
            waiters = list(self._waiters)
        for loop, ev in waiters:
            try:
                loop.call_soon_threadsafe(ev.set)
            except RuntimeError:  # loop closed
                pass

    async def listen(self, timeout: float) -> str | None:
        """The next utterance, whatever it says (the Core's command listening), or None."""
        loop = asyncio.get_running_loop()
        ev = asyncio.Event()
        entry = (loop, ev)
        with self._lock:
            if self._heard:
                return self._heard.popleft()
            self._waiters.append(entry)
        try:
            try:
                await asyncio.wait_for(ev.wait(), timeout)
            except asyncio.TimeoutError:
                pass
            with self._lock:
                return self._heard.popleft() if self._heard else None
        finally:
            with self._lock:
                self._waiters.remove(entry)

    def clear(self) -> None:
        with self._lock:
            self._heard.clear()

    @staticmethod
    def match(words: list[str], text: str) -> str | None:
        low = " " + re.sub(r"[^\w\s]", " ", text.lower()) + " "
        low = re.sub(r"\s+", " ", low)
        for w in words:
            if f" {w.lower().strip()} " in low:
                return w
        return None

    async def spot(self, words: list[str], timeout: float) -> tuple[str | None, str | None]:
        loop = asyncio.get_running_loop()
        ev = asyncio.Event()
        entry = (loop, ev)
        deadline = loop.time() + timeout
        with self._lock:
            self._waiters.append(entry)
        try:
            while True:
                ev.clear()
                while True:
                    with self._lock:
                        text = self._heard.popleft() if self._heard else None
                    if text is None:
                        break
                    w = self.match(words, text)
                    if w is not None:
                        return w, text
                remaining = deadline - loop.time()
                if remaining <= 0:
                    return None, None
                try:
                    await asyncio.wait_for(ev.wait(), remaining)
                except asyncio.TimeoutError:
                    pass
        finally:
            with self._lock:
                self._waiters.remove(entry)


# ------------------------------------------------------------------------------ the microphone's audio
class AudioInput:
    """The audio path of a robot's microphone (beside Microphone's typed utterances): what the house
    sounds like at the robot's head, in simulation time."""

    def __init__(self, robot: "Robot", house: "HouseSound"):
        self.robot, self.house = robot, house
        self.name = robot.name

    def position(self) -> tuple[float, float, float]:
        x, y, _ = self.robot.pose
        return x, y, self.robot.spec.collision_height + 0.05  # microphones sit in the head / top plate

    def record(self, position, t0: float, seconds: float, rate: int = 16000) -> np.ndarray:
        """int16 samples heard at `position` over [t0, t0 + seconds) (CPU work: call from an executor)."""
        return self.house.receive(position, t0, seconds, mic=self.name, rate=rate)

    def microphones(self) -> tuple[tuple[float, float, float], ...]:
        """The array's microphones in the robot's frame (one at the listening point where it has none)."""
        return self.robot.spec.microphones or ((0.0, 0.0, 0.0),)

    def record_array(self, position, heading: float, t0: float, seconds: float) -> np.ndarray:
        """record() at each microphone (channels, n), the head at `position` turned `heading` (CPU work)."""
        from .mic_array import heads_mics
        mics = heads_mics(self.microphones(), heading) + np.asarray(position, float)[None]
        return self.house.receive_array(mics, t0, seconds, mic=self.name)


def fresh_front_end(decoder) -> None:
    """Forget what the front end learnt of earlier utterances: its noise estimate (the model's
    `remove_noise`) carries over from one utterance to the next, so a kept decoder's answer depended
    on the audio it had decoded before (a margin of 0.101 became 0.128 after two other recordings).
    After this, an answer depends on its own audio only, and a decoder can be kept (~75 ms to make)."""
    decoder.reinit_feat()


def sphinx_config(**kw):
    """A pocketsphinx configuration of the bundled US English model (no search yet)."""
    from pocketsphinx import Config, get_model_path
    return Config(hmm=get_model_path("en-us/en-us"), dict=get_model_path("en-us/cmudict-en-us.dict"),
                  samprate=16000, lm=None, loglevel="FATAL", **kw)


def frame_levels(frames: np.ndarray) -> np.ndarray:
    """Each 10 ms frame's level (n, hop) -> (n,) dB of its mean square (+1: silence is 0 dB)."""
    return 10 * np.log10(np.mean(np.asarray(frames, np.float64) ** 2, axis=1) + 1.0)


def speech_segments(pcm: np.ndarray, rate: int = 16000, margin_db: float = 9.0, min_speech: float = 0.15,
                    max_gap: float = 0.35, pad: float = 0.2) -> list[tuple[int, int]]:
    """Sample ranges where someone speaks: 10 ms frames louder than the recording's own floor (its
    20th percentile, so a steady TV or fan raises the bar) by `margin_db`, gaps up to `max_gap` bridged."""
    hop = rate // 100
    n = len(pcm) // hop
    if n == 0:
        return []
    db = frame_levels(pcm[:n * hop].reshape(n, hop))
    loud = db > np.percentile(db, 20) + margin_db
    runs, start, quiet = [], None, 0
    for i, v in enumerate(loud):
        if v:
            start = i if start is None else start
            quiet = 0
        elif start is not None:
            quiet += 1
            if quiet * hop > max_gap * rate:
                runs.append((start, i - quiet + 1))
                start, quiet = None, 0
    if start is not None:
        runs.append((start, n - quiet))
    p = int(pad * rate)
    return [(max(0, s * hop - p), min(len(pcm), e * hop + p)) for s, e in runs if (e - s) * hop >= min_speech * rate]


class PhraseDecoder:
    """pocketsphinx on 16 kHz int16 audio: a JSGF grammar of phrases, checked against a free phone loop
    (a phrase is accepted only when its path scores at least as well as any phone sequence: the
    owner said one of the phrases, not something else). Not thread-safe: one per thread or call.
    Each `decode` starts from a fresh front end, so its answer depends on that audio alone."""

    def __init__(self, phrases: list[str] | None = None, jsgf: str | None = None, trust_search: bool = False,
                 words: list[str] = (), beams: dict | None = None):
        from pocketsphinx import Decoder, get_model_path
        self.decoder = Decoder(sphinx_config(**(beams or {})))  # beams: e.g. WIDE_BEAMS
        # trust_search: the search's own best path, when a complete phrase, is the answer (see decode)
        self.trust_search = trust_search
        self.unknown: list[str] = []
        # words of the phrases (or of `words`, for a grammar's) missing from the dictionary, pronounced
        # by robots/pronounce.py; those it cannot pronounce are listed in `unpronounced`
        self.added, self.unpronounced = self._pronounce(list(phrases or []) + list(words))
        if jsgf is None:
            known = [p for p in dict.fromkeys(normalize(p) for p in phrases or []) if p and self.known(p)]
            self.unknown = [p for p in phrases or [] if normalize(p) not in known]
            self.phrases = known
            jsgf = grammar(known) if known else None
        else:
            self.phrases = []
        self.has_grammar = jsgf is not None
        self._single: dict[str, str] = {}  # phrase -> the search of a grammar of it alone (least recent first)
        self._made = 0
        if jsgf is not None:
            try:
                self.decoder.add_jsgf_string("phrases", jsgf)
            except (RuntimeError, ValueError) as e:
                raise InvalidArgument(f"bad JSGF grammar: {e}") from None
        self.decoder.add_allphone_file("phones", get_model_path("en-us/en-us-phone.lm.bin"))

    # wider than pocketsphinx's defaults (1e-48, 7e-29, 1e-48): with those, the Platform's search of
    # the Store's sentences pruned the one said and reached no sentence's end ("tell me the forecast"
    # in eSpeak's American voices lost to "do i have ..." early on). On bench/speech_offline.py's
    # recordings (2026-11-27, anechoic, four microphones) the Platform path's commands right went from
    # 82/83/80 to 82/83/84 of 84 (quiet/TV 50/TV 60), other sentences taken 11 -> 10 of 144, and a
    # decode took ~25 ms more. In a 0.3 s room it costs: 80/73/20 -> 81/72/14, and other sentences
    # taken 4 -> 11 (quiet 0 -> 6 of 48, mostly "turn on the radio"). Narrower (1e-60, 1e-40) did not
    # reach the sentence's end with one microphone. The Core's keyword spotter keeps the defaults:
    # there it moved as many keywords each way, and took "quiz" for "email" once
    WIDE_BEAMS = dict(beam=1e-80, wbeam=1e-60, pbeam=1e-80)

    def known(self, phrase: str) -> bool:
        return all(self.decoder.lookup_word(w) for w in phrase.split())

    MAX_ADDED = 500  # words pronounced for one decoder (~2 ms each: eSpeak NG is loaded per word)

    def _pronounce(self, phrases: list[str]) -> tuple[list[str], list[str]]:
        """Give the dictionary the phrases' words it lacks: (added, without a pronunciation)."""
        from .pronounce import pronunciation
        missing = [w for w in dict.fromkeys(w for p in phrases for w in normalize(p).split())
                   if not self.decoder.lookup_word(w)]
        added, failed = [], []
        for w in missing:
            phones = pronunciation(w) if len(added) < self.MAX_ADDED else None
            if phones is None:
                failed.append(w)
                continue
            self.decoder.add_word(w, phones, False)
            added.append(w)
        return added, failed

    def _run(self, search: str, pcm: np.ndarray):
        d = self.decoder
        d.activate_search(search)
        d.start_utt()
        d.process_raw(np.asarray(pcm, "<i2").tobytes(), False, True)
        d.end_utt()
        return d.hyp()

    def decode(self, pcm: np.ndarray, accept: float = 0.0) -> tuple[str | None, float]:
        """(phrase heard or None, margin: how much better the phrase's path scores than the phone loop's,
        log-score per second; >= `accept` accepts). `segments` then holds (word, first, last 10 ms frame).

        pocketsphinx's grammar search ends wherever the best path is, often inside a phrase (a prefix
        such as "read" of "read my e-mail" outscores the keyword "quiz" that was said). Then the answer
        is the best *complete* phrase among the search's N-best, aligned alone to the audio (its score
        then depends on that phrase only). With `trust_search`, when the search's best path is a
        complete phrase, it is the answer: aligned alone, a longer phrase can outscore the short one
        said (the cognitive game's "six", in a grammar of the numbers 0-300, lost to "thirty five" in 2
        of 8 recordings); the runner-up then only sets the lead. (The Core's keywords keep the best
        aligned phrase: measured on the speech benchmark that way.) The answer's aligned score is
        compared with the free phone loop: the owner said the phrase, not something else."""
        self.segments: list[tuple[str, int, int]] = []
        self.lead, self.runner_up = math.inf, None
        if not self.has_grammar:
            return None, 0.0
        fresh_front_end(self.decoder)
        candidates = self._complete_phrases(pcm)
        if not candidates:
            return None, -math.inf
        aligned = sorted((a for a in map(lambda w: self._align(w, pcm), candidates) if a is not None),
                         key=lambda a: -a[1])
        if not aligned:
            return None, -math.inf
        first = next((a for a in aligned if a[0] == candidates[0]), None)
        if self.trust_search and self._best_path_complete and first is not None:
            aligned.remove(first)
            aligned.insert(0, first)  # the search's own complete answer (its lead over the runner-up may be < 0)
        words, score, self.segments = aligned[0]
        seconds = max(len(pcm) / 16000, 0.1)
        # how clearly the phrase beats the runner-up (log-score per second; inf: no other complete phrase)
        self.lead = (score - aligned[1][1]) / seconds if len(aligned) > 1 else math.inf
        self.runner_up = aligned[1][0] if len(aligned) > 1 else None
        loop = self._run("phones", pcm)
        margin = (score - math.log(max(loop.score if loop else 0.0, 1e-300))) / seconds
        return (words if margin >= accept else None), float(margin)

    KEPT_SINGLE = 64  # grammars of one phrase kept for _align
    NBEST = 40  # lattice paths looked through for complete phrases
    CANDIDATES = 2  # complete phrases aligned (~15 ms each)

    def _complete_phrases(self, pcm: np.ndarray) -> list[str]:
        hyp = self._run("phrases", pcm)
        self._best_path_complete = False
        if hyp is None:
            return []
        known = set(self.phrases) if self.phrases else None
        out: list[str] = []
        first = [hyp.hypstr.strip()]
        try:
            more = [nb.hypstr.strip() for nb, _ in zip(self.decoder.nbest(), range(self.NBEST)) if nb is not None]
        except (RuntimeError, TypeError):  # no lattice (nothing decoded)
            more = []
        for words in first + more:
            if words and (known is None or words in known) and words not in out:
                out.append(words)
                if len(out) >= self.CANDIDATES:
                    break
        self._best_path_complete = bool(out) and out[0] == first[0]
        return out

    def _align(self, words: str, pcm: np.ndarray) -> tuple[str, float, list[tuple[str, int, int]]] | None:
        """(words, log-score, segments) of a grammar of `words` alone on the audio (the same search as the
        phrases', so its score compares with the phone loop's as before), or None where the search
        does not reach the phrase's end."""
        d = self.decoder
        search = self._single.pop(words, None)
        if search is None:
            self._made += 1
            search = f"one{self._made}"
            d.add_jsgf_string(search, grammar([words]))
        self._single[words] = search
        if len(self._single) > self.KEPT_SINGLE:  # a kept decoder of a word loop meets ever new phrases
            d.remove_search(self._single.pop(next(iter(self._single))))
        hyp = self._run(search, pcm)
        if hyp is None or hyp.hypstr.strip() != words:
            return None
        segments = [(s.word, s.start_frame, s.end_frame) for s in d.seg()]
        return words, math.log(max(hyp.score, 1e-300)), segments


def normalize(phrase: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"[^\w\s']", " ", phrase.lower())).strip()


def grammar(phrases: list[str], repeat: bool = False) -> str:
    """A JSGF grammar: one of the phrases (repeat: any sequence of them)."""
    body = " | ".join(f"({p})" for p in phrases)
    rule = f"( {body} )+" if repeat else body
    return f"#JSGF V1.0;\ngrammar phrases;\npublic <phrase> = {rule};\n"


# a RApp's word spotting: how far below the phone loop's score an isolated word may be. A short word's
# margin moves with where the cut falls (the owner's timing): measured at 1 m, 8 onsets 14 ms apart
# (en-us), the cognitive game's "five" +0.135..+0.168, "six" -0.007..+0.023 (one in 8 refused at 0:
# the game by voice heard 1 of 2 answers), "nine" +0.004..+0.021; against [weather, hazards, stop]
# (en-us+m3) "hello there" -0.042..-0.079, "thank you" -0.096 and below, "banana" no word at all. A
# looser bound (-0.08) once took "banana" for "hazards" in tests/robots/test_sound.py. ("open the
# window" came out "stop" at +0.03 in 3 of 6 onsets: no bound on this margin tells those apart.)
WORD_SPOTTING_ACCEPT = -0.02


async def spot_in_audio(audio: AudioInput, world, words: list[str], timeout: float, chunk: float = 0.5
                        ) -> tuple[str | None, str | None]:
    """Listen (simulation time) for an isolated keyword: record in chunks, cut utterances at pauses,
    decode each with a grammar of the words. (word, what was heard) or (None, None) at the timeout.

    The sound is heard from the request on, every sample of it: each chunk is recorded from the end of
    the one before up to the world's time, however far the world went on meanwhile (others driving it
    while a chunk was decoded, the decoder built on a slow CPU): late, never lost."""
    loop = asyncio.get_running_loop()
    t_next = world.time
    t_end = t_next + timeout
    dec = await loop.run_in_executor(None, partial(PhraseDecoder, words, trust_search=True))
    if not dec.phrases:
        await world.sleep(max(0.0, t_end - world.time))  # no word the recogniser knows: the microphone only passes time
        return None, None
    by_norm = {normalize(w): w for w in words}
    buf = np.zeros(0, np.int16)
    while t_next < t_end - 1e-9:
        if world.time < min(t_next + chunk, t_end) - 1e-9:
            await world.sleep(min(t_next + chunk, t_end) - world.time)
        t0, step = t_next, min(world.time, t_end) - t_next
        t_next = t0 + step
        buf = np.concatenate([buf, await loop.run_in_executor(None, audio.record, audio.position(), t0, step)])
        segs = speech_segments(buf)
        done = [s for s in segs if s[1] < len(buf) - 0.35 * 16000] or (segs if t_next >= t_end - 1e-9 else [])
        for s, e in done:
            heard, _ = await loop.run_in_executor(None, dec.decode, buf[s:e], WORD_SPOTTING_ACCEPT)
            if heard is not None:
                return by_norm.get(heard, heard), heard
        if done:
            buf = buf[done[-1][1]:]
        buf = buf[-int(8 * 16000):]  # an utterance longer than 8 s is not an isolated keyword
    return None, None


# ------------------------------------------------------------------------------ continuous listening
class VoiceActivity:
    """Streaming voice activity detection on 16 kHz int16 chunks (the Core's continuous listening).

    A 10 ms frame is speech when it stands out from the room's recent non-speech sound (the last
    `floor_seconds` of frames outside utterances) in either of two ways:
      level: louder than that sound's `level_pct` percentile by `margin_db` (a steady fan or the mic's
             own noise is beaten by any voice near enough);
      shape: its 16 band spectrum (robots/denoise.py), level removed, departs from the noise's usual
             band shape more than nine in ten of the noise's own frames do (`shape_pct` percentile,
             + `shape_margin_db`): a TV's sound swells and fades with its programme but keeps its
             spectrum; a voice over it changes the spectrum even where it is no louder.
    An utterance starts after `start_frames` speech frames in a row and ends after `end_silence` s
    without; once that silence has lasted `resume_after` s, only `resume_frames` speech frames in a
    row end it (the mic's own noise alone passes for speech in ~3 % of its frames, most of them one
    at a time, and each held an utterance open up to 0.3 s longer). `feed` returns the finished ones
    (with `pad` s of audio before and after). One longer than `max_seconds` is returned once, cut,
    with `too_long` set, and the rest of it is skipped."""

    def __init__(self, rate: int = 16000, margin_db: float = 6.0, start_frames: int = 5, end_silence: float = 0.3,
                 pad: float = 0.2, max_seconds: float = 10.0, floor_seconds: float = 5.0, min_speech: float = 0.2,
                 level_pct: float = 90.0, shape_pct: float = 90.0, shape_margin_db: float = 0.5,
                 resume_frames: int = 2, resume_after: float = 0.1):
        if rate != 16000:
            raise InvalidArgument(f"voice activity detection needs 16 kHz audio, not {rate} Hz")
        self.rate, self.hop = rate, rate // 100
        self.margin_db, self.start_frames = margin_db, start_frames
        self.resume_frames, self.resume_after = resume_frames, round(resume_after * 100)
        self.level_pct, self.shape_pct, self.shape_margin_db = level_pct, shape_pct, shape_margin_db
        self.end_frames, self.pad_frames = round(end_silence * 100), round(pad * 100)
        self.max_frames, self.min_frames = round(max_seconds * 100), round(min_speech * 100)
        n = round(floor_seconds * 100)
        self.history: deque[float] = deque(maxlen=n)  # frame levels (dB) outside utterances
        self.band_history: deque[np.ndarray] = deque(maxlen=n)  # their band spectra (dB)
        self.shape_history: deque[float] = deque(maxlen=n)  # their shape distance (dB)
        self.bands = BandSpectra()
        self._last_distance: float | None = None
        self._held: list[tuple[float, np.ndarray, float]] = []  # the current utterance's frames
        self.before: deque[tuple[np.ndarray, bool]] = deque(maxlen=self.pad_frames + start_frames)
        self.frames: list[np.ndarray] = []  # the utterance so far
        self.loud: list[bool] = []  # which of its frames were taken for speech
        self.loud_run = self.quiet_run = self.speech_frames = 0
        self.skipping = False  # the rest of an over-long sound
        self._rest = np.zeros(0, np.int16)
        self.heard_s = 0.0  # sound fed so far (s)
        self.cut_s: float | None = None  # heard_s when the last utterance was cut (its end of silence)
        self.started_s: float | None = None  # heard_s when the current (or last) utterance was taken to start

    @property
    def active(self) -> bool:
        return bool(self.frames) or self.skipping

    def learn_room_from(self, other: "VoiceActivity") -> None:
        """Take what another detector on the same microphone has learnt of the room's sound (until it has
        heard 30 frames of it, a detector takes nothing for speech: an owner's word then is learnt as noise)."""
        if len(other.history) > len(self.history):
            self.history = deque(other.history, maxlen=self.history.maxlen)
            self.band_history = deque(other.band_history, maxlen=self.band_history.maxlen)
            self.shape_history = deque(other.shape_history, maxlen=self.shape_history.maxlen)

    def relearn_room(self, pcm: np.ndarray) -> None:
        """Forget what was learnt of the room's sound and learn it from `pcm` (nobody speaking in it)
        instead: what the detector hears has changed (robots/mic_array.py Steering's new filter), and
        sound judged against the old would differ from it in level and shape as a voice does."""
        n = len(pcm) // self.hop
        if n < 30:
            return
        frames = np.asarray(pcm[-n * self.hop:], np.int16).reshape(n, self.hop)
        db = frame_levels(frames)
        bands = BandSpectra().feed_frames(frames)
        shape = np.median(bands - bands.mean(axis=1, keepdims=True), axis=0)
        distance = _shape_distance(bands[1:], shape, float(_shape_distance(bands[:1], shape)[0]))
        self.history = deque(db, maxlen=self.history.maxlen)
        self.band_history = deque(bands, maxlen=self.band_history.maxlen)
        self.shape_history = deque(distance, maxlen=self.shape_history.maxlen)
        self._last_distance = None

    def reset(self) -> None:
        """Forget any utterance in progress (the robot itself spoke meanwhile)."""
        self.frames, self.loud, self.skipping = [], [], False
        self.before.clear()
        self.loud_run = self.quiet_run = self.speech_frames = 0

    def _learn(self, frames) -> None:
        for db, bands, d in frames:
            self.history.append(db)
            self.band_history.append(bands)
            if not math.isnan(d):
                self.shape_history.append(d)

    def _thresholds(self) -> tuple[float, np.ndarray, float] | None:
        """(level threshold dB, noise band shape, shape threshold dB) from the recent non-speech frames."""
        if len(self.history) < 30:
            return None
        level = float(np.percentile(self.history, self.level_pct)) + self.margin_db
        bands = np.asarray(self.band_history)
        shape = np.median(bands - bands.mean(axis=1, keepdims=True), axis=0)
        if len(self.shape_history) >= 30:
            limit = float(np.percentile(self.shape_history, self.shape_pct)) + self.shape_margin_db
        else:
            limit = math.inf
        return level, shape, limit

    def feed(self, pcm: np.ndarray) -> list["HeardUtterance"]:
        x = np.concatenate([self._rest, np.asarray(pcm, np.int16)])
        heard_before = self.heard_s - len(self._rest) / self.rate
        self.heard_s += len(pcm) / self.rate
        n = len(x) // self.hop
        self._rest = x[n * self.hop:]
        out: list[HeardUtterance] = []
        if n == 0:
            return out
        frames = x[:n * self.hop].reshape(n, self.hop)
        energies = frame_levels(frames)
        bands = self.bands.feed_frames(frames)
        limits = self._thresholds()  # once per chunk: the noise changes slowly
        if limits is not None:
            level, shape, shape_limit = limits
            distance = _shape_distance(bands, shape, self._last_distance)
            self._last_distance = float(distance[-1])
        for i, (frame, db) in enumerate(zip(frames, energies)):
            loud = False
            d = math.nan
            if limits is not None:
                d = float(distance[i])
                loud = db > level or d > shape_limit
            noise = (float(db), bands[i], d)
            if not self.frames:  # the room's own sound (an over-long one too): what utterances are judged against
                self._learn([noise])
            else:
                self._held.append(noise)
            was_active = self.active
            got = self._step(frame, loud)
            if self.frames and not was_active:
                self.started_s = heard_before + (i + 1) * self.hop / self.rate
            if not self.frames:
                if got is not None and got.too_long:  # a TV switched on, not a command: it is the room now
                    self._learn(self._held)
                self._held = []
            if got is not None:
                out.append(got)
                self.cut_s = heard_before + (i + 1) * self.hop / self.rate
                # its trailing silence beyond the pad is not part of it
                kept_silence = 0 if got.too_long else (self.end_frames - self.pad_frames) * self.hop
                got.end_sample = round(self.cut_s * self.rate) - kept_silence
        return out

    def _step(self, frame: np.ndarray, loud: bool) -> "HeardUtterance | None":
        if self.skipping:
            self.quiet_run = 0 if loud else self.quiet_run + 1
            if self.quiet_run >= self.end_frames:
                self.reset()
            return None
        if not self.frames:
            self.before.append((frame, loud))
            self.loud_run = self.loud_run + 1 if loud else 0
            if self.loud_run >= self.start_frames:
                self.frames, self.loud = [f for f, _ in self.before], [f for _, f in self.before]
                self.speech_frames, self.quiet_run = self.loud_run, 0
                self.before.clear()
            return None
        self.frames.append(frame)
        self.loud.append(loud)
        self.speech_frames += loud
        # a silence of `resume_after` ends only with `resume_frames` loud in a row (one alone is the
        # room's noise); a shorter one with any (a weak voice's frames in a TV are loud one in two)
        if loud and (self.quiet_run < self.resume_after or all(self.loud[-self.resume_frames:])):
            self.quiet_run = 0
        else:
            self.quiet_run += 1
        if len(self.frames) >= self.max_frames:
            got = HeardUtterance(np.concatenate(self.frames), self.speech_frames / 100, too_long=True,
                                 loud=np.array(self.loud))
            self.frames, self.loud, self.skipping, self.quiet_run = [], [], True, 0
            return got
        if self.quiet_run >= self.end_frames:
            got = self._padded()
            self.reset()
            return got if got.speech_seconds >= self.min_frames / 100 else None
        return None

    def _padded(self) -> "HeardUtterance":
        """The utterance so far, `pad` s of its silence kept (a lone loud frame in the silence left
        out is not its speech: the cut then equals what `ending` said before it)."""
        keep = len(self.frames) - self.quiet_run + self.pad_frames
        speech = self.speech_frames - sum(self.loud[keep:])
        return HeardUtterance(np.concatenate(self.frames[:keep]), speech / 100, loud=np.array(self.loud[:keep]))

    def ending(self) -> "HeardUtterance | None":
        """The utterance this detector will cut unless speech comes again, as soon as it is known: after
        `pad` s of silence its audio is fixed, and the rest of `end_silence` only confirms the end. A
        listener may start on it meanwhile (the Core spots a keyword in it): the cut, if it comes, is
        equal to it (pcm, loud, speech, end_sample). None while speech goes on or when it would not count."""
        if self.skipping or not self.frames or self.quiet_run < self.pad_frames:
            return None
        got = self._padded()
        if got.speech_seconds < self.min_frames / 100:
            return None
        fed = round(self.heard_s * self.rate) - len(self._rest)  # samples up to the last frame judged
        got.end_sample = fed - (self.quiet_run - self.pad_frames) * self.hop
        return got


def _shape_distance(bands: np.ndarray, shape: np.ndarray, before: float | None = None) -> np.ndarray:
    """How far each frame's band spectrum (level removed) departs from the room's usual `shape` (dB),
    each averaged with the frame's before (`before`: the distance of the one before the first; None:
    not averaged): one odd frame is no voice."""
    rel = bands - bands.mean(axis=1, keepdims=True) - shape
    distance = np.sqrt(np.mean((rel - rel.mean(axis=1, keepdims=True)) ** 2, axis=1))
    if before is None:
        return distance
    return np.convolve(np.concatenate([[before], distance]), [0.5, 0.5], "valid")


@dataclass
class HeardUtterance:
    """A stretch of speech the microphone heard: int16 samples at 16 kHz."""

    pcm: np.ndarray
    speech_seconds: float  # loud frames in it
    too_long: bool = False
    bearing: float | None = None  # radians, robot's frame: where a microphone array heard it from
    end_sample: int = 0  # samples fed to its detector up to its last one (a Steering's: DELAY after the microphones')
    loud: np.ndarray | None = None  # per 10 ms of pcm: whether the detector took it for speech

    @property
    def seconds(self) -> float:
        return len(self.pcm) / 16000

    def then(self, more: "HeardUtterance") -> "HeardUtterance":
        """This utterance and the next as one: a sentence the detector cut where the speaker paused
        (each keeps its padding, so the pause stays about as long as it was)."""
        loud = None if self.loud is None or more.loud is None else np.concatenate([self.loud, more.loud])
        return HeardUtterance(np.concatenate([self.pcm, more.pcm]), self.speech_seconds + more.speech_seconds,
                              self.too_long or more.too_long, end_sample=more.end_sample, loud=loud)


class KeywordSpotter:
    """Is an utterance one of `keywords`, said alone? A grammar of the keywords and the command phrases
    (so a sentence is recognised as the sentence it is, not squeezed into a keyword), the best complete
    phrase checked against a free phone loop (PhraseDecoder), and a keyword taken only when it covers
    most of the speech the detector heard (`min_cover`: one word of a sentence is not said alone).
    Decoders are per thread (pocketsphinx is not thread-safe) and kept (building one takes ~90 ms of
    the 500 ms budget).
    `groups` (keyword -> its RApp) lets a close runner-up that means the same (hazard / hazards) pass;
    a runner-up of another group closer than MIN_LEAD is not understood rather than guessed."""

    MAX_KEYWORD_SECONDS = 1.6  # of speech: longer is a sentence, whatever it sounds like
    # how far the keyword's path may score below the phone loop's (log-score per second). -0.04 for
    # the owner's commands: on bench/speech_offline.py's recordings (2026-11-26) 0.0 refused 7 of
    # 54 keywords said in a quiet room (margins -0.04..0) and -0.04 refused 1, with one more of 144 other
    # sentences started as a RApp and no wrong RApp more. A spotted supervision word ends the
    # owner's task: those keep 0.0 (STRICT).
    ACCEPT = -0.04
    STRICT = 0.0
    MIN_LEAD = 0.01  # log-score per second over a runner-up keyword of another group
    # a keyword said alone is most of the speech heard: the keyword's aligned words cover at least this
    # share of the detector's speech seconds, less the echo after them (said_alone). On
    # bench/speech_offline.py's recordings (2026-11-26) the keywords spotted right covered 0.78-1.02 of it;
    # of the sentences and other keywords taken for a keyword ("thank you very much" -> "email", "quiz"
    # in the TV -> "mail"), all but one covered 0.20-0.69.
    # A supervision word keeps 0: "stop, stop!" stops the robot (STRICT guards it)
    MIN_COVER = 0.75

    def __init__(self, keywords: list[str], phrases: list[str] = (), groups: dict[str, str] | None = None,
                 accept: float = ACCEPT, min_cover: float = MIN_COVER):
        self.accept, self.min_cover = accept, min_cover
        self.keywords = {normalize(k): k for k in keywords if normalize(k)}
        self.phrases = [p for p in dict.fromkeys(normalize(p) for p in phrases) if p and p not in self.keywords]
        self.groups = {normalize(k): g for k, g in (groups or {}).items()}
        self._decoders: dict[int, PhraseDecoder] = {}
        self._lock = threading.Lock()

    def _decoder(self) -> PhraseDecoder:
        key = threading.get_ident()
        with self._lock:
            dec = self._decoders.get(key)
        if dec is None:
            dec = PhraseDecoder(list(self.keywords) + self.phrases)
            with self._lock:
                self._decoders[key] = dec
        return dec

    def warm_up(self) -> None:
        self._decoder()

    def spot(self, utterance: HeardUtterance) -> str | None:
        """The keyword said (as given), or None: not a keyword alone (CPU work: call from an executor)."""
        if not self.keywords or utterance.speech_seconds > self.MAX_KEYWORD_SECONDS:
            return None
        dec = self._decoder()
        heard, _ = dec.decode(utterance.pcm, accept=self.accept)
        if heard is None or heard not in self.keywords:
            return None
        if not said_alone(utterance, [(first, last) for w, first, last in dec.segments if w[:1] not in "<["],
                          self.min_cover):
            return None  # one word of something longer: the Platform hears it whole (s4b)
        other = dec.runner_up
        if other is not None and dec.lead < self.MIN_LEAD and self._group(other) != self._group(heard):
            return None  # two different commands fit about equally well: ask again rather than guess
        return self.keywords[heard]

    def _group(self, words: str) -> str:
        return self.groups.get(words, words)


ECHO_DB = 15.0  # this far below the words' loudest 10 ms, the speech after them is the room's echo of them


MAX_OTHER_SPEECH_S = 0.1  # of the detector's speech outside a keyword said alone (less its echo)


def said_alone(utterance: HeardUtterance, words: list[tuple[int, int]], share: float = KeywordSpotter.MIN_COVER) -> bool:
    """Whether `words` (first and last 10 ms frame of each, in the utterance's audio) are what the
    utterance said, and not one part of something longer: they cover `share` of the speech the
    detector heard in it, and leave at most MAX_OTHER_SPEECH_S of that speech outside them. In a
    furnished room the detector hears a word's echo as speech for a few hundred ms after it; the
    speech after the words quieter than their loudest frame by ECHO_DB is that echo, not more words
    (on bench/speech_offline.py's recordings, 2026-11-27: the words after a keyword within 15 dB, the
    echo of a keyword said alone below it), and is not counted. On those recordings the keywords
    spotted right left at most 0.06 s outside them, with one microphone or four; the sentences taken
    for a keyword 0.13-0.7 s (the decoder had aligned "thank you" of "thank you very much" as
    silence, and "email" over the rest). `share` 0: any words will do ("stop, stop!")."""
    if not words:
        return False
    if share <= 0:
        return True
    first, last = min(f for f, _ in words), max(la for _, la in words)
    echo = echo_seconds(utterance, first, last)
    said = sum(la - f + 1 for f, la in words) / 100
    if said < share * max(utterance.speech_seconds - echo, 0.01):
        return False
    if utterance.loud is None:
        return True
    loud = utterance.loud[:len(utterance.pcm) // 160]
    inside = sum(int(np.count_nonzero(loud[f:la + 1])) for f, la in words)
    return (np.count_nonzero(loud) - inside) / 100 - echo <= MAX_OTHER_SPEECH_S


def echo_seconds(utterance: HeardUtterance, first: int, last: int) -> float:
    """Speech the detector heard after frame `last` ECHO_DB or more below the loudest frame of
    `first`..`last`: the room's echo of those words (0 when the utterance has no loud frames kept)."""
    n = 0 if utterance.loud is None else min(len(utterance.loud), len(utterance.pcm) // 160)
    if first >= n or last < first:
        return 0.0
    level = frame_levels(utterance.pcm[:n * 160].reshape(n, 160))
    loudest = level[first:last + 1].max()
    after = slice(last + 1, n)
    return float(np.count_nonzero(utterance.loud[after] & (level[after] < loudest - ECHO_DB))) / 100
