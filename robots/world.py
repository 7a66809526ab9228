"""The simulated home: a PyBullet world built from a house description, robots in it, and the
simulation-time stepper. Every pybullet call for a world runs in ONE dedicated worker thread; camera
images are rendered in render processes mirroring the scene (render="process", default) or in that
thread (render="inline").

    world = World.from_file(HOUSES / "small.yaml", seed=1, overrides={"doors": {"d1": 45}})
    nao = world.add_robot("nao")             # start pose from the description (seeded)
    await world.sleep(1.0)                   # simulation seconds
    world.ground_truth()                     # true poses, door angles, lamp states (tests/scoring only)

Things that move (people, doors someone swings, dropped boxes) come from a disturbance file
(robots/disturbances.py): World.from_file(..., disturbances=FILE) or world.attach_disturbances(spec).
"""
from __future__ import annotations

import asyncio
import json
import math
import os
import threading
import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
from .pybullet_quiet import p
import yaml

from .bodies import ROBOT_SPECS
from .controllers import Controller, Observer, Timer
from .errors import InvalidArgument, RobotError, WorldClosed
from .floorplan import Plan, load_plan
from .gridmap import GridMap, build_grid_map
from .house_gen import GENERATED, generate
from .lighting import Daylight, with_daylight
from .odometry import OdometryNoise
from .receptors import Camera
from .render_process import RenderPool, SceneState, SharedRenderer
from .robot import Robot
from .scene import Scene
from .simclock import STEP_S, SimClock

if TYPE_CHECKING:
    from .disturbances import ContactEvent, Disturbances, DisturbanceSpec

HOUSES = Path(__file__).parent / "houses"
RENDER_MODES = ("process", "inline")


@dataclass
class GroundTruth:
    time: float
    robots: dict[str, tuple[float, float, float]]
    doors: dict[str, float]  # degrees
    lamps: dict[str, bool]
    movers: dict[str, tuple[float, float, float]] = field(default_factory=dict)  # people and boxes present


class World(Scene):
    """render: "process" (default; env RAPP_ROBOTS_RENDER overrides the default) renders camera images in
    up to `render_workers` separate processes mirroring the scene (robots/render_process.py), so a frame
    neither holds this process's GIL nor waits for / delays physics stepping; "inline" renders in the
    pybullet thread of this process. `render_bands`: a 1280x960 frame in that many bands at once, on idle
    render processes (a world of one robot, whose other core waits while a frame renders). `renderer`:
    a SharedRenderer (robots/render_process.py) whose processes this world renders in, with other
    worlds of the same house (a fleet), instead of processes of its own."""

    def __init__(self, plan: Plan, rtf: float = 0.0, time_step: float = STEP_S, render: str | None = None,
                 render_workers: int | None = None, render_bands: int = 1,
                 disturbances: "str | Path | dict | list | DisturbanceSpec | None" = None,
                 renderer: SharedRenderer | None = None):
        render = render or os.environ.get("RAPP_ROBOTS_RENDER") or "process"
        if render not in RENDER_MODES:
            raise InvalidArgument(f"render must be one of {', '.join(RENDER_MODES)}, not {render!r}")
        if renderer is not None and render != "process":
            raise InvalidArgument(f"a shared renderer renders in its processes: render={render!r} would ignore it")
        self.render_mode = render
        self._renderer: RenderPool | None = None
        self._init_scene(plan)
        self.clock = SimClock(step=time_step, rtf=rtf)
        self._exec = ThreadPoolExecutor(1, thread_name_prefix=f"pybullet-{plan.name}")
        self._worker: threading.Thread | None = None
        self.robots: dict[str, Robot] = {}
        self._active: list[Controller] = []
        self._stepper: asyncio.Task | None = None
        self._closed = False
        self.disturbances: Disturbances | None = None
        self.mapped_plan: Plan = plan  # the house as mapped (from_file's `lived_in` makes them differ)
        self.lived_in: dict | None = None  # what changed since (robots/lived_in.py live_in's account)
        self.daylight: dict | None = None  # the light of its time of day (robots/lighting.py with_daylight)
        # the rooms' ambient and diffuse light beyond the sky's (lit lamps and windows are emissive: unchanged);
        # a validation's dim or bright room (scenarios/hazard_validation.py)
        self.light_scale = 1.0
        self.run_sync(self._build)
        if render == "process" and renderer is not None:
            self._renderer = renderer.view(plan)
        elif render == "process":
            self._renderer = RenderPool(plan, render_workers or min(2, os.cpu_count() or 1), name=plan.name,
                                        bands=render_bands)
        if disturbances is not None:
            try:
                self.attach_disturbances(disturbances)
            except BaseException:
                self.close()
                raise

    @classmethod
    def from_file(cls, path: str | Path, seed: int = 0, overrides: dict | None = None, rtf: float = 0.0,
                  time_step: float = STEP_S, render: str | None = None, render_workers: int | None = None,
                  render_bands: int = 1, disturbances: "str | Path | dict | list | DisturbanceSpec | None" = None,
                  lived_in: "Callable[[Plan], tuple[Plan, dict]] | None" = None,
                  daylight: Daylight | None = None, renderer: SharedRenderer | None = None) -> "World":
        """Build from a YAML house description; `path` may also be a bare name in robots/houses, or
        "generated": the house robots/house_gen.py generates from `seed` (which also seeds the rest).
        `disturbances`: a disturbance file (or bare name in robots/houses) or spec, see attach_disturbances.
        `lived_in`: what changed since the house was mapped (robots/lived_in.py): the world is built
        from the plan it returns, `mapped_plan` keeps the plan as the map knows it. `daylight`: the
        light of a time of day, windows and lamps of several strengths (robots/lighting.py; the
        world's `daylight` says what it drew); None: the studio light."""
        path = Path(path)
        source: Path | dict = path
        if not path.exists() and (HOUSES / f"{path}.yaml").exists():
            source = HOUSES / f"{path}.yaml"
        elif not path.exists() and str(path) == GENERATED:
            source = generate(seed)
        elif not path.exists():
            names = sorted([GENERATED, *(p.stem for p in HOUSES.glob("*.yaml") if not p.stem.endswith("-disturbances"))])
            raise FileNotFoundError(f"no house {str(path)!r}: a house file (YAML) or one of {', '.join(names)}")
        mapped = load_plan(source, seed=seed, overrides=overrides)
        plan, changes = lived_in(mapped) if lived_in is not None else (mapped, None)
        plan, light = with_daylight(plan, daylight) if daylight is not None else (plan, None)
        world = cls(plan, rtf=rtf, time_step=time_step, render=render, render_workers=render_workers,
                    render_bands=render_bands, disturbances=disturbances, renderer=renderer)
        world.mapped_plan, world.lived_in, world.daylight = mapped, changes, light
        return world

    # ------------------------------------------------------------------ thread plumbing
    def _mark_worker(self) -> None:
        self._worker = threading.current_thread()

    def run_sync(self, fn: Callable, *args, **kw) -> Any:
        """Run fn in the pybullet thread and wait (for setup code and tests outside async code)."""
        if self._closed:
            raise WorldClosed("world is closed")
        if threading.current_thread() is self._worker:
            return fn(*args, **kw)
        return self._exec.submit(self._in_worker, fn, *args, **kw).result()

    def _in_worker(self, fn, *args, **kw):
        if self._worker is None:
            self._mark_worker()
        return fn(*args, **kw)

    async def run(self, fn: Callable, *args, **kw) -> Any:
        """Run fn in the pybullet thread without blocking the event loop."""
        if self._closed:
            raise WorldClosed("world is closed")
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._exec, partial(self._in_worker, fn, *args, **kw))

    # ------------------------------------------------------------------ building
    def _build(self) -> None:
        self.cid = p.connect(p.DIRECT)
        self._obstacle_uids: list[int] = []
        self._obstacle_aabbs: list[list[float]] = []
        self._build_scene()

    def _add_obstacle(self, uid: int) -> None:
        self._obstacle_uids.append(uid)
        self._obstacle_aabbs.append(self._aabb(uid))
        self._aabb_array = np.array(self._obstacle_aabbs)

    def _aabb(self, uid: int) -> list[float]:
        lo, hi = np.array(p.getAABB(uid, -1, physicsClientId=self.cid))
        for link in range(p.getNumJoints(uid, physicsClientId=self.cid)):
            l2, h2 = np.array(p.getAABB(uid, link, physicsClientId=self.cid))
            lo, hi = np.minimum(lo, l2), np.maximum(hi, h2)
        return [lo[0], lo[1], hi[0], hi[1]]

    # ------------------------------------------------------------------ obstacles / state
    def obstacles_near(self, x: float, y: float, r: float, exclude: int = -1) -> list[int]:
        a = self._aabb_array
        hit = (a[:, 0] - r <= x) & (x <= a[:, 2] + r) & (a[:, 1] - r <= y) & (y <= a[:, 3] + r)
        out = [self._obstacle_uids[i] for i in np.nonzero(hit)[0]]
        for rb in self.robots.values():
            if rb.probe != exclude and math.hypot(rb.pose[0] - x, rb.pose[1] - y) < r + rb.spec.radius + 0.1:
                out.append(rb.probe)
        if self.disturbances is not None:  # people and dropped boxes stop robots too
            out += self.disturbances.bodies_near(x, y, r)
        return out

    def set_door_in_thread(self, door_id: str, angle_deg: float) -> None:
        super().set_door_in_thread(door_id, angle_deg)
        uid = self.door_uids[door_id]
        self._obstacle_aabbs[self._obstacle_uids.index(uid)] = self._aabb(uid)
        self._aabb_array = np.array(self._obstacle_aabbs)

    async def set_door(self, door_id: str, angle_deg: float) -> None:
        await self.run(self.set_door_in_thread, door_id, angle_deg)

    async def set_lamp(self, lamp_id: str, on: bool) -> None:
        await self.run(self._set_lamp, lamp_id, on)

    def ground_truth(self) -> GroundTruth:
        """True state for tests and scenario scoring; never exposed through RobotAPI."""
        return GroundTruth(self.clock.time, {n: r.pose for n, r in self.robots.items()},
                           {d.id: d.angle for d in self.plan.doors}, {lp.id: lp.on for lp in self.plan.lamps},
                           self.disturbances.poses() if self.disturbances is not None else {})

    # ------------------------------------------------------------------ disturbances
    def attach_disturbances(self, spec: "str | Path | dict | list | DisturbanceSpec") -> "Disturbances":
        """Add the people, door swings and dropped boxes of a disturbance file (path, or bare name in
        robots/houses) or spec (robots/disturbances.py); their times are simulation time from the world's
        start, applied at every step. Raises DisturbanceError (an InvalidArgument) on a bad spec."""
        from .disturbances import Disturbances, load_disturbances  # pydantic only for worlds that use it

        if self.disturbances is not None:
            raise InvalidArgument("this world already has disturbances attached")
        dist = Disturbances(load_disturbances(spec, search=HOUSES), self.plan)
        self.run_sync(dist.build, self)
        self.disturbances = dist
        return dist

    def person_contacts(self, robot: str | None = None) -> int:
        """Touching episodes between robots (or `robot`) and people so far (one per episode)."""
        return self.disturbances.contacts("person", robot) if self.disturbances is not None else 0

    def object_contacts(self, robot: str | None = None) -> int:
        """Touching episodes between robots (or `robot`) and dropped boxes so far."""
        return self.disturbances.contacts("box", robot) if self.disturbances is not None else 0

    async def touch(self, robot: str, sensor: str, seconds: float = 0.3) -> None:
        """Press a robot's touch sensor (a NAO's head_front, head_middle, head_rear, hand_left, hand_right)
        now, for `seconds` of simulation time: what a person touching it does (RobotAPI.get_contacts and
        the Core's "touch" events report it). InvalidArgument for an unknown robot or sensor."""
        await self.run(self.touch_in_thread, robot, sensor, seconds)

    def touch_in_thread(self, robot: str, sensor: str, seconds: float) -> None:
        """touch, from the world's pybullet thread (a scenario file's touch, robots/disturbances.py)."""
        r = self.robots.get(robot)
        if r is None or r.contacts is None:
            raise InvalidArgument(f"no robot {robot!r} with touch sensors (robots: {', '.join(self.robots) or 'none'})")
        r.contacts.touch(sensor, self.clock.time, seconds)

    def contact_events(self) -> "list[ContactEvent]":
        return list(self.disturbances.events) if self.disturbances is not None else []

    # ------------------------------------------------------------------ robots
    def add_robot(self, kind: str, name: str | None = None, pose: tuple[float, float, float] | None = None,
                  odometry_noise: OdometryNoise | None = None) -> Robot:
        """Add a robot of a type of ontology/robot_types.py ("nao", "elektron"). Without `pose` the description's start spec (fixed or a seeded
        random pose in a room/region) is used. Returns the Robot; wrap it in RobotAPI for async use."""
        if kind not in ROBOT_SPECS:
            raise InvalidArgument(f"unknown robot kind {kind!r} (known: {', '.join(ROBOT_SPECS)})")
        spec = ROBOT_SPECS[kind]
        name = name or kind
        if name in self.robots:
            raise InvalidArgument(f"robot {name!r} already exists")
        if pose is None:
            pose = self.plan.start_pose(name, kind, spec.radius)
        rng = np.random.default_rng([self.plan.seed, zlib.crc32(f"odometry/{name}".encode())])
        robot = self.run_sync(Robot, self, spec, name, tuple(pose), odometry_noise, rng)
        self.robots[name] = robot
        return robot

    # ------------------------------------------------------------------ cameras
    def _render_request(self, cam: Camera, width: int, height: int) -> tuple:
        """pybullet thread: camera matrices and the dynamic scene state, consistent with the sim time."""
        view, proj = cam.view_projection(width, height)
        state = SceneState({n: (r.kind, r.pose, dict(r.q)) for n, r in list(self.robots.items())},
                           {d.id: d.angle for d in self.plan.doors}, {lp.id: lp.on for lp in self.plan.lamps},
                           self.disturbances.scene_bodies() if self.disturbances is not None else {},
                           self.light_scale)
        return state, width, height, view, proj, cam.params

    async def capture(self, cam: Camera, width: int, height: int) -> np.ndarray:
        """RGB uint8 image (HxWx3) of `cam` with its image parameters applied, rendered in a render process
        (the scene state is taken at the current simulation time; stepping goes on meanwhile) or inline."""
        if self._renderer is None:
            return await self.run(cam.capture, width, height)
        req = await self.run(self._render_request, cam, width, height)
        if self._closed:
            raise WorldClosed("world is closed")
        return await self._renderer.render_async(*req)

    def capture_sync(self, cam: Camera, width: int, height: int) -> np.ndarray:
        """Blocking capture (setup code, tests and scripts outside async code)."""
        if self._renderer is None:
            return self.run_sync(cam.capture, width, height)
        return self._renderer.render(*self.run_sync(self._render_request, cam, width, height))

    def start_renderer(self, processes: int | None = None, own_session: bool = False) -> None:
        """Start the render processes now (blocking, ~0.5 s each) rather than at the first captures;
        `own_session`: each in a session of its own, whose scheduling group can be set apart."""
        if self._renderer is not None:
            self._renderer.own_session = own_session
            self._renderer.warm_up(processes)

    def render_pids(self) -> list[int]:
        return self._renderer.pids() if self._renderer is not None else []

    # ------------------------------------------------------------------ simulation time
    @property
    def time(self) -> float:
        return self.clock.time

    def start(self, ctrl: Controller) -> asyncio.Future:
        """Register a controller (event-loop thread); the returned future resolves when it finishes."""
        if self._closed:
            raise WorldClosed("world is closed")
        loop = asyncio.get_running_loop()
        ctrl.future = loop.create_future()
        self._active.append(ctrl)
        if self._stepper is None or self._stepper.done():
            self.clock.restart_pacing()
            self._stepper = loop.create_task(self._step_loop(), name=f"world-stepper-{self.plan.name}")
        return ctrl.future

    async def sleep(self, seconds: float, drive: bool = True) -> None:
        """Wait `seconds` of simulation time (all active motions advance meanwhile). `drive=False`:
        only wait for time that others make pass (an unpaced world is not stepped for this)."""
        if seconds > 0:
            await self.start(Timer(seconds) if drive else Observer(seconds))

    async def sync(self) -> None:
        """Wait until the pybullet thread has finished everything submitted before."""
        await self.run(lambda: None)

    def finishing_steps(self) -> bool:
        """Event-loop thread: does a robot stopped mid-step (mechanical drive) still walk that step, with no
        motion of its own under way? Such a step keeps an unpaced world stepping until it ends."""
        for r in list(self.robots.values()):
            base = r.controllers.get("base")
            if (r.locomotion is not None and r.locomotion.finishing()
                    and (base is None or base.done or base.cancelled)):
                return True
        return False

    def keep_stepping(self) -> None:
        """Event-loop thread, after a motion was stopped: step the world while a stopped walk finishes its step."""
        if self._closed or not self.finishing_steps():
            return
        if self._stepper is None or self._stepper.done():
            self.clock.restart_pacing()
            self._stepper = asyncio.get_running_loop().create_task(self._step_loop(), name=f"world-stepper-{self.plan.name}")

    async def _step_loop(self) -> None:
        while not self._closed:
            self._active = [c for c in self._active if not c.done and not c.cancelled]
            active = list(self._active)
            finishing_only = False
            if not active or (self.clock.rtf <= 0 and not any(c.blocking for c in active)):
                if not self.finishing_steps():
                    break
                finishing_only = self.clock.rtf <= 0  # unpaced: only until the steps are done
            finished = await self.run(self._advance, active, self.clock.chunk_steps(), finishing_only)
            for c in finished:
                c.resolve()
            delay = self.clock.delay()
            await asyncio.sleep(delay)

    def _advance(self, active: list[Controller], n: int, finishing_only: bool = False) -> list[Controller]:
        dt = self.clock.step
        finished: list[Controller] = []
        for _ in range(n):
            if finishing_only and not any(r.locomotion is not None and r.locomotion.finishing()
                                          for r in self.robots.values()):
                break
            for c in active:
                if c.done or c.cancelled:
                    continue
                try:
                    if c.step(dt):
                        c.done = True
                        finished.append(c)
                except Exception as e:  # noqa: BLE001 - any failure ends the motion and reaches the caller
                    c.done, c.error = True, e if isinstance(e, RobotError) else RobotError(f"{type(e).__name__}: {e}")
                    finished.append(c)
            for r in self.robots.values():  # a walk stopped mid-step finishes it (mechanical drive)
                if r.locomotion is not None:
                    r.locomotion.tick(r, dt)
            self.clock.time += dt
            if self.disturbances is not None:
                self.disturbances.advance(self.clock.time)
            for r in self.robots.values():
                if r.contacts is not None:  # bumpers against what the step moved, touches that end
                    r.contacts.step(self.clock.time)
            if any(c.blocking for c in finished):
                break
        return finished

    # ------------------------------------------------------------------ maps
    def grid_map(self, resolution: float = 0.05, include_doors: bool = False) -> GridMap:
        return build_grid_map(self.plan, resolution=resolution, include_doors=include_doors)

    def export_grid_map(self, directory: str | Path, name: str = "map", resolution: float = 0.05,
                        include_doors: bool = False) -> tuple[Path, Path]:
        """Write <name>.png + <name>.yaml (ROS map_server format)."""
        return self.grid_map(resolution, include_doors).save(directory, name)

    @property
    def landmarks(self):
        return list(self.plan.landmarks)

    def landmark_map(self) -> dict[str, Any]:
        return {"frame": "map", "convention": "yaw = panel normal (into the room); size = QR symbol side "
                "without quiet zone; corners TL, TR, BR, BL as seen facing the panel",
                "landmarks": [m.to_dict() for m in self.plan.landmarks]}

    def write_landmark_map(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        data = self.landmark_map()
        path.write_text(json.dumps(data, indent=1) if path.suffix == ".json" else yaml.safe_dump(data, sort_keys=False))
        return path

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        if self._closed:
            return
        for c in self._active:
            c.cancel(WorldClosed("world closed"))
        if self._stepper is not None and not self._stepper.done():
            self._stepper.cancel()
        if self._renderer is not None:
            self._renderer.close()
        try:
            self._exec.submit(p.disconnect, physicsClientId=self.cid).result()
        finally:
            self._closed = True
            self._exec.shutdown(wait=True)

    def __enter__(self) -> "World":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
