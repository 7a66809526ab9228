"""A robot-API wrapper the scenario owns: passes every call to the real RobotAPI and records ground
truth around it (scoring only; the RApp never sees it): the true pose at each set_global_pose, the
true trajectory (sampled every `sample_s` simulation seconds) during each move_along_path, and the
camera frames captured right after a look_at_point (the hazard checks)."""
from __future__ import annotations

import asyncio
import base64
import math
from pathlib import Path

import numpy as np


def distance_to_polyline(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance of each point (n, 2) to the polyline (m, 2)."""
    if len(poly) == 1:
        return np.linalg.norm(points - poly[0], axis=1)
    a, b = poly[:-1], poly[1:]
    ab = b - a
    denom = np.maximum((ab ** 2).sum(1), 1e-12)
    ap = points[:, None, :] - a[None, :, :]
    t = np.clip((ap * ab[None]).sum(2) / denom[None], 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=2).min(1)


# the Core polls these on its own (safety, obstacle events, listening for "stop") while a task runs
SENSOR_READS = frozenset({"get_sonars", "get_laser_scan", "get_global_pose", "capture_audio", "microphone_energy"})


class RecordingAPI:
    def __init__(self, api, frames_dir: str | Path | None = None, sample_s: float = 0.1,
                 every_capture: bool = False):
        self.api, self.robot, self.world = api, api.robot, api.world
        self.frames_dir = Path(frames_dir) if frames_dir else None
        self.every_capture = every_capture  # else only captures right after look_at_point (checks)
        self.sample_s = sample_s
        self.localizations: list[dict] = []  # time, estimate, truth, error_m
        self.paths: list[dict] = []  # poses (planned leg), trajectory (true), tracking_error_m
        self.frames: list[Path] = []
        self._last = ""
        # live views (scenarios.watch): the leg being driven, the latest image and how many so far
        self.current_path: list[list[float]] | None = None
        self.latest_image = None  # ontology.robot.Image
        self.captures = 0
        self.sink = None  # a run's recording (scenarios/recording.py RobotSink): what it keeps of the calls

    # robots.interface.RobotInterface: what is not recorded goes to the real API
    @property
    def microphone(self):
        return self.api.microphone

    def moving_forward(self, min_speed: float = 0.02) -> bool:
        return self.api.moving_forward(min_speed)

    def capabilities(self) -> frozenset[str]:
        return self.api.capabilities()

    async def handle(self, req):
        name = req.action_name
        try:
            if name == "set_global_pose":
                return await self._set_pose(req)
            if name == "move_along_path":
                return await self._follow(req)
            reply = await self.api.handle(req)
            if self.sink is not None:
                self.sink.reply(name, reply)
            if name == "capture_image":
                self.latest_image, self.captures = reply, self.captures + 1
            if name == "capture_image" and (self.every_capture or self._last == "look_at_point"):
                self._save_frame(reply)
            return reply
        finally:
            if name not in SENSOR_READS:  # the Core's own sensor polling must not sit between look and capture
                self._last = name

    async def _set_pose(self, req):
        tx, ty, tth = self.robot.pose
        err = math.hypot(req.x - tx, req.y - ty)
        dth = math.atan2(math.sin(req.theta - tth), math.cos(req.theta - tth))
        self.localizations.append({"time": self.world.time, "estimate": [req.x, req.y, req.theta],
                                   "truth": [tx, ty, tth], "error_m": err, "heading_error_rad": dth})
        if self.sink is not None:
            self.sink.estimate(req.x, req.y, req.theta)
        return await self.api.handle(req)

    async def _follow(self, req):
        samples: list[tuple[float, float]] = []
        done = asyncio.Event()

        async def sample():
            while not done.is_set():
                samples.append(tuple(self.robot.pose[:2]))
                await self.world.sleep(self.sample_s)

        sampler = asyncio.create_task(sample())
        self.current_path = [[p.x, p.y] for p in req.poses]
        if self.sink is not None:
            self.sink.path([[p.x, p.y, p.theta] for p in req.poses])
        try:
            return await self.api.handle(req)
        finally:
            self.current_path = None
            done.set()
            samples.append(tuple(self.robot.pose[:2]))
            await asyncio.gather(sampler, return_exceptions=True)
            poses = np.array([[p.x, p.y] for p in req.poses], float)
            traj = np.array(samples, float)
            err = float(distance_to_polyline(traj, poses).max()) if len(traj) else 0.0
            self.paths.append({"poses": poses.tolist(), "trajectory": traj.tolist(), "tracking_error_m": err})

    def _save_frame(self, image) -> None:
        if self.frames_dir is None:
            return
        self.frames_dir.mkdir(parents=True, exist_ok=True)
        ext = "jpg" if image.encoding == "jpeg" else "png"  # a noisy camera's frames travel as JPEG
        path = self.frames_dir / f"{'frame' if self.every_capture else 'check'}_{len(self.frames) + 1:02d}.{ext}"
        path.write_bytes(base64.b64decode(image.data_b64))
        self.frames.append(path)

    # scores -------------------------------------------------------------------------------
    def localization_error(self) -> float:
        return max((r["error_m"] for r in self.localizations), default=float("nan"))

    def tracking_error(self) -> float:
        return max((p["tracking_error_m"] for p in self.paths), default=float("nan"))

    def __getattr__(self, name):  # anything else (the Core may call RobotAPI methods directly)
        return getattr(self.api, name)
