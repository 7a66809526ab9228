"""`--watch`: a live page of a run on http://127.0.0.1:PORT/ - the map of the house, the robot (its
pose and driven trail), its planned paths (the leg being driven highlighted), the latest camera
frame, and the Core's and RApp's states, progress and chat (from scenarios.progress.RunView).

The server is aiohttp on the run's own event loop: each request only reads the state object (a
pose tuple, the recorder's lists, the latest image), so nothing blocks the run and nothing reads
PyBullet from another thread. The page is self-contained (no CDN) and polls /state.json.

    state = WatchState(home_map(world, house), pose=lambda: recorder.robot.pose, recorder=recorder, view=view)
    server = WatchServer(state, port=8765)
    print(f"[watch] {await server.start()}")
    ...
    await server.stop()
"""
from __future__ import annotations

import asyncio
import base64
import contextlib
import math

import cv2
from aiohttp import web

from .watch_page import PAGE

DEFAULT_PORT = 8765
NO_STORE = {"Cache-Control": "no-store"}


class WatchState:
    """What the page shows, read at each poll. `pose()` -> (x, y, theta) (the true pose: the
    scenario's view, not the RApp's estimate); `recorder` a scenarios.recorder.RecordingAPI (planned
    legs, current leg, latest image); `view` a scenarios.progress.RunView (states, chat, progress)."""

    def __init__(self, grid, pose=None, recorder=None, view=None, title: str = "rapp run",
                 trail_step_m: float = 0.02):
        self.grid, self.pose, self.recorder, self.view, self.title = grid, pose, recorder, view, title
        self.trail: list[tuple[float, float]] = []  # the driven trail, a point every trail_step_m
        self.trail_step_m = trail_step_m
        self._map_png: bytes | None = None

    def map_png(self) -> bytes:
        if self._map_png is None:  # a few hundred pixels a side: encoded once, in microseconds
            ok, buf = cv2.imencode(".png", self.grid.image)
            self._map_png = buf.tobytes()
        return self._map_png

    def map_meta(self) -> dict:
        h, w = self.grid.image.shape[:2]
        return {"width": w, "height": h, "resolution": self.grid.resolution,
                "origin": [float(self.grid.origin[0]), float(self.grid.origin[1])]}

    def current_pose(self) -> tuple[float, float, float] | None:
        p = self.pose() if self.pose is not None else None
        return None if p is None else (float(p[0]), float(p[1]), float(p[2]))

    def sample(self) -> None:
        """Extend the trail with the pose now (when it moved far enough)."""
        p = self.current_pose()
        if p is not None and (not self.trail or math.dist(self.trail[-1], p[:2]) >= self.trail_step_m):
            self.trail.append((round(p[0], 3), round(p[1], 3)))

    def frame(self) -> tuple[bytes, str] | None:
        image = getattr(self.recorder, "latest_image", None)
        data = getattr(image, "data_b64", None)
        if not data:
            return None
        encoding = getattr(image, "encoding", "png")
        return base64.b64decode(data), f"image/{'jpeg' if encoding in ('jpg', 'jpeg') else encoding}"

    def snapshot(self, trail_from: int = 0, legs_known: int = -1) -> dict:
        """JSON data of the page: the trail from point `trail_from` on, the finished planned legs
        only when the page knows another number of them."""
        self.sample()
        rec = self.recorder
        legs = [p["poses"] for p in getattr(rec, "paths", [])]
        trail_from = trail_from if 0 <= trail_from <= len(self.trail) else 0
        out = {"title": self.title, "pose": self.current_pose(), "trail_from": trail_from,
               "trail": self.trail[trail_from:], "trail_total": len(self.trail),
               "legs_total": len(legs), "current_leg": getattr(rec, "current_path", None),
               "captures": getattr(rec, "captures", 0)}
        if legs_known != len(legs):
            out["legs"] = legs
        world = getattr(rec, "world", None)
        if world is not None:
            out["sim_time"] = round(float(world.time), 2)
        if self.view is not None:
            out["run"] = self.view.snapshot()
        return out


class WatchServer:
    """The page's HTTP server, on 127.0.0.1 only (no authentication: never on another address)."""

    def __init__(self, state: WatchState, port: int = DEFAULT_PORT, host: str = "127.0.0.1",
                 sample_s: float = 0.2):
        self.state, self.port, self.host, self.sample_s = state, port, host, sample_s
        self._runner: web.AppRunner | None = None
        self._sampler: asyncio.Task | None = None
        self.url = ""

    async def _sample(self) -> None:  # the trail also grows while no page is open
        while True:
            self.state.sample()
            await asyncio.sleep(self.sample_s)

    def _app(self) -> web.Application:
        async def index(_):
            return web.Response(text=PAGE, content_type="text/html", headers=NO_STORE)

        async def map_png(_):
            return web.Response(body=self.state.map_png(), content_type="image/png")

        async def meta(_):
            return web.json_response(self.state.map_meta())

        async def state(request):
            q = request.query
            try:
                trail_from, legs_known = int(q.get("trail_from", 0)), int(q.get("legs", -1))
            except ValueError:
                raise web.HTTPBadRequest(text="trail_from and legs are numbers")
            return web.json_response(self.state.snapshot(trail_from, legs_known), headers=NO_STORE)

        async def frame(_):
            got = self.state.frame()
            if got is None:
                raise web.HTTPNotFound(text="no camera frame yet")
            return web.Response(body=got[0], content_type=got[1], headers=NO_STORE)

        app = web.Application()
        app.add_routes([web.get("/", index), web.get("/map.png", map_png), web.get("/map.json", meta),
                        web.get("/state.json", state), web.get("/frame", frame)])
        return app

    async def start(self) -> str:
        """Serve; the page's address. A port in use falls back to a free one."""
        self._runner = web.AppRunner(self._app(), access_log=None)  # no log lines over the live panel
        await self._runner.setup()
        try:
            await web.TCPSite(self._runner, self.host, self.port).start()
        except OSError:
            if self.port == 0:
                raise
            await web.TCPSite(self._runner, self.host, 0).start()
        host, port = self._runner.addresses[0][:2]
        self.url = f"http://{host}:{port}/"
        self._sampler = asyncio.create_task(self._sample())
        return self.url

    async def stop(self) -> None:
        if self._sampler is not None:
            self._sampler.cancel()
            await asyncio.gather(self._sampler, return_exceptions=True)
            self._sampler = None
        if self._runner is not None:
            with contextlib.suppress(Exception):
                await self._runner.cleanup()
            self._runner = None
