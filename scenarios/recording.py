"""A run's recording, made by the scenario's own (trusted) process while the run goes on
(docs/recordings.md): the whole message bodies beside the trace (agents/tracing.py record_bodies),
the RApp packages its Cores run (packages/), long strings such as camera frames once each (blobs/),
and robot.jsonl, what each simulated robot did and
sensed (ontology/recording.py RobotSample): the map, its true pose every SAMPLE_S simulated seconds,
the estimates it was told (set_global_pose), the paths it was asked to follow, laser and sonar scans
(at most one per SCAN_S simulated seconds each) and camera frames (every capture; `frames=False`
leaves them out). At the end run.mcap is assembled from all of it (scenarios/mcap_export.py).

    rec = Recording(out, world, {"nao": recording_api}, grid)   # before the system starts
    rec.start(); ...; await rec.finish()                          # run.mcap written
"""
from __future__ import annotations

import asyncio
import base64
import json
import os
import shutil
import threading
import time
from pathlib import Path

import cv2

from agents.tracing import BLOBS, BODIES, blob_store_for, record_bodies, stop_recording_bodies

ROBOT_LOG = "robot.jsonl"
MCAP_FILE = "run.mcap"
SAMPLE_S = 0.2  # simulated seconds between true-pose samples
SCAN_S = 0.5  # simulated seconds between recorded scans of one sensor


class RobotLog:
    """robot.jsonl: one JSON object a line, appended by this process only (0600: it holds frames)."""

    def __init__(self, path: Path, world):
        self.path, self.world = Path(path), world
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_TRUNC, 0o600)
        self._lock = threading.Lock()
        self.count = 0

    def write(self, kind: str, robot: str = "", **fields) -> None:
        if self._fd is None:
            return
        line = json.dumps({"t": round(time.time(), 6), "sim": round(self.world.time, 4), "kind": kind,
                           "robot": robot, **fields}, separators=(",", ":")) + "\n"
        with self._lock:
            if self._fd is not None:
                os.write(self._fd, line.encode())
                self.count += 1

    def close(self) -> None:
        with self._lock:
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None


class RobotSink:
    """What a scenarios.recorder.RecordingAPI tells the recording about one robot."""

    def __init__(self, log: RobotLog, robot: str, frames: bool, blobs=None):
        self.log, self.robot, self.frames, self.blobs = log, robot, frames, blobs
        self._last_scan: dict[str, float] = {}

    def estimate(self, x: float, y: float, theta: float) -> None:
        self.log.write("estimate", self.robot, pose=[x, y, theta])

    def path(self, poses: list[list[float]]) -> None:
        self.log.write("path", self.robot, poses=poses)

    def reply(self, name: str, reply) -> None:
        """A robot-API reply worth keeping: scans (rate-limited) and camera frames."""
        if name == "get_laser_scan" or name == "get_sonars":
            now = self.log.world.time
            if now - self._last_scan.get(name, -1e9) < SCAN_S:
                return
            self._last_scan[name] = now
            self.log.write("laser" if name == "get_laser_scan" else "sonar", self.robot, **reply.model_dump())
        elif name == "capture_image" and self.frames:
            self.log.write("image", self.robot, camera=reply.camera, encoding=reply.encoding,
                           width=reply.width, height=reply.height,
                           # the same frame the Core's answer carried: one blob for both (agents/tracing.py)
                           data_b64=self.blobs.put(reply.data_b64) if self.blobs is not None else reply.data_b64)


class Recording:
    def __init__(self, out: str | Path, world, apis: dict, grid=None, frames: bool = True):
        self.out, self.world, self.apis, self.grid, self.frames = Path(out), world, apis, grid, frames
        self.trace = self.out / "trace.jsonl"
        self.log: RobotLog | None = None
        self._samplers: list[asyncio.Task] = []
        self.mcap: Path | None = None

    def begin(self) -> None:
        """Before the system starts (its agents then write the message bodies too)."""
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / BODIES).unlink(missing_ok=True)
        shutil.rmtree(self.out / BLOBS, ignore_errors=True)
        record_bodies(self.trace)
        blobs = blob_store_for(self.trace)
        self.log = RobotLog(self.out / ROBOT_LOG, self.world)
        if self.grid is not None:
            ok, png = cv2.imencode(".png", self.grid.image)
            self.log.write("map", resolution=self.grid.resolution, origin=list(self.grid.origin),
                           png_b64=base64.b64encode(png.tobytes()).decode())
        for kind, api in self.apis.items():
            api.sink = RobotSink(self.log, kind, self.frames, blobs)

    def start(self) -> None:
        """Sample the true poses (once the loop runs)."""
        self._samplers = [asyncio.create_task(self._sample(kind, api.robot)) for kind, api in self.apis.items()]

    async def _sample(self, kind: str, robot) -> None:
        while True:
            x, y, theta = robot.pose[:3]
            self.log.write("pose", kind, pose=[round(x, 4), round(y, 4), round(theta, 5)])
            await self.world.sleep(SAMPLE_S, drive=False)  # observe; never run the world ahead

    def stop(self) -> None:
        """The samplers and the body recording end (after the system has stopped)."""
        for task in self._samplers:
            task.cancel()
        for api in self.apis.values():
            api.sink = None
        stop_recording_bodies(self.trace)
        if self.log is not None:
            self.log.close()

    async def finish(self) -> Path | None:
        """stop(), then run.mcap from the run folder (None, and the reason printed, if it failed)."""
        from .mcap_export import export_mcap

        self.stop()
        try:
            self.mcap = await asyncio.to_thread(export_mcap, self.out, self.out / MCAP_FILE, frames=self.frames)
        except Exception as e:  # noqa: BLE001 - the run's other files stand; the export can be re-run
            print(f"[record] run.mcap not written: {type(e).__name__}: {e} "
                  f"(rapp trace export --format mcap {self.out})", flush=True)
            self.mcap = None
        return self.mcap
