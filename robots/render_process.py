"""Camera rendering in separate processes that mirror a World's scene.

PyBullet's TinyRenderer holds the GIL for the whole getCameraImage call (~30 ms at 320x240, 0.5-2 s at
1280x960), which starves the event loop of the process and serialises rendering with physics stepping.
A RenderPool keeps up to N render processes (default: 2, one per core); each builds the same static
scene from the same house description with the same code as World (robots/scene.py, robots/multibody.py),
in its own DIRECT client. Per request it receives only the dynamic state that changed since its last
request (robot base poses and joint angles, door angles, lamp states, the people and dropped boxes of
robots/disturbances.py) plus the view/projection matrices, renders with ER_TINY_RENDERER, applies the
camera image parameters and returns the uint8 RGB image through a pipe. The caller waits in a thread (a thread blocked on a pipe releases the GIL), so neither
the event loop nor the world's pybullet thread waits for the renderer.

Processes start lazily (the first request starts one; a second one starts only when a request arrives
while the first is busy), are restarted once if they die, and are stopped by RenderPool.close()
(World.close()), at interpreter exit (weakref.finalize), and by themselves when the parent goes away
(EOF on their request pipe). They are plain `python -c` children (subprocess), not multiprocessing
children, so the parent's __main__ is never re-imported.

Several Worlds of one house may share one pool (SharedRenderer: a fleet, each robot in its own copy
of the house): before each frame the mirror takes the requesting world's doors, lamps, robots and
moving bodies, and parks what belongs to none of them out of view. A render process holds ~140 MB
(Pss) once it has rendered a 1280x960 frame; one per world was most of a fleet robot's memory.

Protocol (multiprocessing.connection framing, pickle): parent -> child ("init", plan) then
("render", RenderJob) ... ("close",); child -> parent ("ready",) / ("ok", image) / ("error", traceback).
"""
from __future__ import annotations

import asyncio
import dataclasses
import itertools
import os
import subprocess
import sys
import threading
import time
import traceback
import weakref
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from ontology.errors import ErrorCode

from .errors import RobotError, WorldClosed


START_TIMEOUT = 60.0  # s for a render process to build its scene
RENDER_TIMEOUT = 300.0  # s for one frame (1280x960 takes ~2 s on a loaded machine)
SPLIT_MIN_PIXELS = 1280 * 960  # with bands, frames this large are rendered in bands, by the idle processes at once
# where a shared mirror keeps a robot or a moving body the rendering world does not have: far beyond
# any camera's far plane (TinyRenderer clips it)
PARKED = (1.0e4, 1.0e4, 0.0)


@dataclass
class SceneState:
    """Dynamic state of a world that affects images (snapshot taken in the world's pybullet thread)."""

    robots: dict[str, tuple[str, tuple[float, float, float], dict[str, float]]]  # name -> (kind, pose, q)
    doors: dict[str, float]  # degrees
    lamps: dict[str, bool]
    bodies: dict[str, tuple] = field(default_factory=dict)  # people, boxes: id -> (shape, position, orientation)
    light_scale: float = 1.0  # the World's room light beyond the sky's (World.light_scale)


@dataclass
class RenderJob:
    width: int
    height: int
    view: list[float]
    proj: list[float]
    params: Any  # receptors.ImageParams; None: the radiance (float HxWx3) of a band, for the parent to join
    add: list[tuple[str, str, tuple[float, float, float]]] = field(default_factory=list)  # (name, kind, pose)
    poses: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    joints: dict[str, dict[str, float]] = field(default_factory=dict)
    doors: dict[str, float] = field(default_factory=dict)
    lamps: dict[str, bool] = field(default_factory=dict)
    bodies: dict[str, tuple] = field(default_factory=dict)  # created when new, else moved (robots/disturbances.py)
    light_scale: float = 1.0  # every job carries it: one float


def band_projection(proj, band: int, bands: int) -> list[float]:
    """The projection matrix (OpenGL, column-major) of band `band` (0 = top) of `bands` equal horizontal
    bands of the frame `proj` projects to, rendered at the band's height: NDC y' = bands * y - (bands -
    1 - 2 band). TinyRenderer then samples the band's pixels where it samples them in the whole frame."""
    P = np.asarray(proj, float).reshape(4, 4).T  # rows of the matrix
    P[1] = bands * P[1] - (bands - 1 - 2 * band) * P[3]
    return [float(v) for v in P.T.reshape(-1)]


# ====================================================================== child side
def _mirror_scene_class():
    from .bodies import ROBOT_SPECS
    from .frames import yaw_quat
    from .lighting import room_light
    from .multibody import create_bodies, probe_z
    from .pybullet_quiet import p
    from .receptors import apply_params, render_radiance
    from .scene import Scene

    class MirrorScene(Scene):
        def __init__(self, plan):
            self._init_scene(plan)
            self.cid = p.connect(p.DIRECT)
            self._build_scene()
            self.bodies: dict[str, tuple[int, int, dict[str, int], Any]] = {}
            self.movers: dict[str, int] = {}

        def apply(self, job: RenderJob) -> None:
            cid = self.cid
            for name, kind, pose in job.add:
                spec = ROBOT_SPECS[kind]
                uid, probe, _ = create_bodies(cid, spec, pose, collision=False)
                joints = {p.getJointInfo(uid, i, physicsClientId=cid)[1].decode(): i
                          for i in range(p.getNumJoints(uid, physicsClientId=cid))}
                self.bodies[name] = (uid, probe, joints, spec)
            for name, (x, y, th) in job.poses.items():
                uid, probe, _, spec = self.bodies[name]
                q = yaw_quat(th)
                p.resetBasePositionAndOrientation(uid, [x, y, 0.0], q, physicsClientId=cid)
                p.resetBasePositionAndOrientation(probe, [x, y, probe_z(spec)], q, physicsClientId=cid)
            for name, qs in job.joints.items():
                uid, _, joints, _ = self.bodies[name]
                for j, a in qs.items():
                    p.resetJointState(uid, joints[j], a, physicsClientId=cid)
            for door_id, angle in job.doors.items():
                self.set_door_in_thread(door_id, angle)
            for lamp_id, on in job.lamps.items():
                self._set_lamp(lamp_id, on)
            for name, (shape, pos, orn) in job.bodies.items():
                if name not in self.movers:
                    from .disturbances import create_body
                    self.movers[name] = create_body(cid, shape, collision=False)
                p.resetBasePositionAndOrientation(self.movers[name], pos, orn, physicsClientId=cid)

        def render(self, job: RenderJob) -> np.ndarray:
            self.apply(job)
            if hasattr(job.params, "render_depth"):  # a depth image (robots/depth_camera.py), not colour
                return job.params.render_depth(self.cid, job.width, job.height, job.view, job.proj)
            radiance = render_radiance(self.cid, job.width, job.height, job.view, job.proj, self.emissive,
                                       room_light(self.plan.sky) * job.light_scale)
            return radiance if job.params is None else apply_params(radiance, job.params)

    return MirrorScene


def serve(fd_in: int, fd_out: int) -> None:
    """Render-process main loop (runs in the child)."""
    _exit_with_parent()
    unmap_large_allocations()
    conn_in, conn_out = Connection(fd_in, writable=False), Connection(fd_out, readable=False)
    scene = None
    try:
        while True:
            try:
                msg = conn_in.recv()
            except (EOFError, OSError):  # parent closed the pipe or died
                return
            try:
                if msg[0] == "close":
                    return
                if msg[0] == "init":
                    scene = _mirror_scene_class()(msg[1])
                    reply: tuple = ("ready",)
                elif msg[0] == "render":
                    reply = ("ok", scene.render(msg[1]))
                else:
                    reply = ("error", f"unknown request {msg[0]!r}")
            except Exception:  # noqa: BLE001 - report to the parent, keep serving
                reply = ("error", traceback.format_exc())
            try:
                conn_out.send(reply)
            except OSError:
                return
    finally:
        conn_in.close()
        conn_out.close()


MMAP_THRESHOLD = 128 * 1024  # glibc's initial threshold, kept
_M_MMAP_THRESHOLD = -3  # mallopt's parameter (malloc.h)


def unmap_large_allocations(threshold: int = MMAP_THRESHOLD) -> bool:
    """Keep glibc's malloc from holding a frame's freed buffers: allocations from `threshold` bytes up
    are mapped on their own and unmapped when freed. glibc raises its threshold to the size of each
    large block freed (up to 32 MB), after which a frame's arrays (15-20 MB at 1280x960) come from the
    heap, which keeps them when freed: ~60 MB of a render process's Pss, measured (bench/RESULTS.md).
    False where the C library has no mallopt (not glibc)."""
    import ctypes

    try:
        return bool(ctypes.CDLL(None).mallopt(_M_MMAP_THRESHOLD, threshold))
    except (AttributeError, OSError):
        return False


def _exit_with_parent() -> None:
    """The pipe's EOF ends the loop when the parent dies, unless a process the parent forked without
    exec still holds its end (seen: render processes orphaned for minutes after a killed benchmark):
    a watch on the parent's pid ends the child within a second either way."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(0)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


# `import robots` loads no simulator (robots/__init__.py loads World, RobotAPI, ... when first used): the
# child imports what a render needs and no more
_BOOT = """
import sys
sys.path.insert(0, {root!r})
from robots.render_process import serve
serve(int(sys.argv[1]), int(sys.argv[2]))
"""


# ====================================================================== parent side
class _Worker:
    """One render process and what it knows of the dynamic state (for sending differences only)."""

    def __init__(self, index: int):
        self.index = index
        self.proc: subprocess.Popen | None = None
        self.send_conn: Connection | None = None
        self.recv_conn: Connection | None = None
        self.busy = False
        self.known: SceneState | None = None

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def start(self, plan_msg: tuple, own_session: bool = False) -> None:
        root = Path(__file__).resolve().parents[1]
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", _BOOT.format(root=str(root)),
                 str(to_child_r), str(from_child_w)],
                pass_fds=(to_child_r, from_child_w), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                close_fds=True, start_new_session=own_session)
        except BaseException:
            for fd in (to_child_r, to_child_w, from_child_r, from_child_w):
                os.close(fd)
            raise
        os.close(to_child_r)
        os.close(from_child_w)
        self.send_conn = Connection(to_child_w, readable=False)
        self.recv_conn = Connection(from_child_r, writable=False)
        self.known = SceneState({}, {}, {})
        self.send_conn.send(plan_msg)
        reply = self._reply(START_TIMEOUT)
        if reply[0] != "ready":
            raise RuntimeError(f"render process failed to start:\n{reply[1]}")

    def _reply(self, timeout: float) -> tuple:
        if not self.recv_conn.poll(timeout):
            raise TimeoutError(f"render process {self.index} did not answer within {timeout:.0f} s")
        return self.recv_conn.recv()

    def job_for(self, state: SceneState, **kw) -> RenderJob:
        """A RenderJob carrying only what changed since this process's last request; robots and
        moving bodies the process shows that `state` lacks (another world's, in a shared pool) are
        parked out of view."""
        job = RenderJob(**kw, light_scale=state.light_scale)
        known = self.known
        state = _with_parked(state, known)
        for name, (kind, pose, q) in state.robots.items():
            old = known.robots.get(name)
            if old is None:
                job.add.append((name, kind, pose))
                job.poses[name] = pose
                job.joints[name] = dict(q)
                continue
            if old[1] != pose:
                job.poses[name] = pose
            changed = {j: a for j, a in q.items() if old[2].get(j) != a}
            if changed:
                job.joints[name] = changed
        job.doors = {k: v for k, v in state.doors.items() if known.doors.get(k) != v}
        job.lamps = {k: v for k, v in state.lamps.items() if known.lamps.get(k) != v}
        job.bodies = {k: v for k, v in state.bodies.items() if known.bodies.get(k) != v}
        return job

    def send(self, state: SceneState, **kw) -> None:
        job = self.job_for(state, **kw)
        self.send_conn.send(("render", job))
        self.known = _with_parked(state, self.known)  # sent: the process applies it even if rendering then fails

    def receive(self) -> np.ndarray:
        reply = self._reply(RENDER_TIMEOUT)
        if reply[0] != "ok":
            raise RenderError(f"render process error:\n{reply[1]}")
        return reply[1]

    def render(self, state: SceneState, **kw) -> np.ndarray:
        self.send(state, **kw)
        return self.receive()

    def stop(self, kill: bool = False, timeout: float = 2.0) -> None:
        """Stop the process: ask it to exit (idle process), or kill it (a thread may be waiting on its pipe:
        that thread then reads EOF and closes the pipes itself). Always reaps it (no zombie)."""
        proc, self.proc = self.proc, None
        if proc is None:
            return
        if not kill and proc.poll() is None and self.send_conn is not None:
            try:
                self.send_conn.send(("close",))
            except OSError:
                pass
        if kill:
            proc.kill()
        else:
            self.close_conns()
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()

    def close_conns(self) -> None:
        for c in (self.send_conn, self.recv_conn):
            if c is not None:
                try:
                    c.close()
                except OSError:
                    pass
        self.send_conn = self.recv_conn = None


def _with_parked(state: SceneState, known: SceneState) -> SceneState:
    """`state` plus, parked, the robots and moving bodies `known` has and `state` lacks."""
    robots = {n: (kind, PARKED, q) for n, (kind, _, q) in known.robots.items() if n not in state.robots}
    bodies = {n: (b[0], PARKED, *b[2:]) for n, b in known.bodies.items() if n not in state.bodies}
    if not robots and not bodies:
        return state
    return dataclasses.replace(state, robots={**robots, **state.robots}, bodies={**bodies, **state.bodies})


class RenderError(RobotError):
    """Rendering failed (the render process reported an exception, or died twice in a row)."""

    code = ErrorCode.RENDER_FAILED


def _kill_all(workers: list[_Worker]) -> None:
    for w in workers:
        if w.proc is not None:
            try:
                w.proc.kill()
                w.proc.wait(5)
            except Exception:  # noqa: BLE001 - best effort at interpreter exit
                pass


class RenderPool:
    """Up to `size` render processes mirroring one World; thread-safe, loop-agnostic."""

    def __init__(self, plan, size: int = 2, name: str = "world", bands: int = 1):
        self.size = max(1, int(size))
        # bands > 1: a large frame in that many bands, each on an idle process (one robot's world: its
        # second core is idle while it renders); 1 (default): a world of many robots, or one of many
        # worlds, keeps its processes busy with whole frames (a band costs 55 %, not 50 %, of a frame)
        self.bands = max(1, int(bands))
        self._plan_msg = ("init", plan)  # pickled when a process starts; later changes arrive as state
        self._workers = [_Worker(i) for i in range(self.size)]
        self._cond = threading.Condition()
        self._closed = False
        self._exec = ThreadPoolExecutor(self.size, thread_name_prefix=f"render-{name}")
        self._finalizer = weakref.finalize(self, _kill_all, self._workers)
        self.restarts = 0
        # processes in sessions of their own: Linux's autogroup schedules each session as one group,
        # so only then can their priority be set apart from their World's process (bench/fleet.py)
        self.own_session = False

    # ---- worker selection
    def _acquire(self) -> _Worker:
        with self._cond:
            while True:
                if self._closed:
                    raise WorldClosed("renderer is closed")
                idle = [w for w in self._workers if not w.busy]
                if idle:
                    w = next((w for w in idle if w.alive), idle[0])  # prefer a running process
                    w.busy = True
                    return w
                self._cond.wait()

    def _release(self, w: _Worker) -> None:
        with self._cond:
            w.busy = False
            self._cond.notify()

    def _idle_others(self, w: _Worker, bands: int) -> list[_Worker]:
        """The other idle processes (marked busy), up to one per band after `w`'s."""
        if bands < 2:
            return []
        with self._cond:
            idle = sorted((x for x in self._workers if not x.busy and x is not w), key=lambda x: not x.alive)
            idle = idle[:bands - 1]
            for x in idle:
                x.busy = True
            return idle

    # ---- rendering
    def render(self, state: SceneState, width: int, height: int, view, proj, params) -> np.ndarray:
        """Blocking: render in a process and return the uint8 RGB image (call from a thread). A large
        frame is rendered in `self.bands` horizontal bands, always (the same pixels however busy the pool
        is), by as many idle processes at once: TinyRenderer's cost is its pixels', a process renders on
        one core."""
        bands = self.bands if width * height >= SPLIT_MIN_PIXELS and height % self.bands == 0 else 1
        w = self._acquire()
        ws = [w, *self._idle_others(w, bands)]
        try:
            for attempt in (0, 1):
                try:
                    for x in ws:
                        if not x.alive:
                            x.close_conns()
                            x.start(self._plan_msg, self.own_session)
                    return self._render_on(ws, bands, state, width, height, view, proj, params)
                except RenderError:
                    self._reset(ws)  # a mirror may be half-updated: the next request starts afresh
                    raise
                except (EOFError, OSError, TimeoutError, RuntimeError) as e:
                    self._reset(ws)
                    if self._closed:
                        raise WorldClosed("renderer closed while rendering") from e
                    if attempt:
                        raise RenderError(f"render process failed: {type(e).__name__}: {e}") from e
                    self.restarts += 1
            raise AssertionError("unreachable")
        finally:
            for x in ws:
                self._release(x)

    @staticmethod
    def _reset(ws: list[_Worker]) -> None:
        for x in ws:  # a reply may be left unread, a mirror half-updated
            x.stop(kill=True, timeout=5.0)
            x.close_conns()

    @staticmethod
    def _render_on(ws: list[_Worker], bands: int, state: SceneState, width: int, height: int, view, proj, params
                   ) -> np.ndarray:
        """The frame in `bands` bands (top first), each process of `ws` one band at a time; the image
        parameters (exposure metered over the whole frame, blur, noise) applied to the joined radiance."""
        if bands == 1:
            return ws[0].render(state, width=width, height=height, view=list(view), proj=list(proj), params=params)
        from .receptors import apply_params

        out = []
        for first in range(0, bands, len(ws)):
            batch = list(zip(range(first, min(bands, first + len(ws))), ws))
            for k, x in batch:
                x.send(state, width=width, height=height // bands, view=list(view),
                       proj=band_projection(proj, k, bands), params=None)
            out += [x.receive() for _, x in batch]
        return apply_params(np.concatenate(out), params)

    async def render_async(self, state: SceneState, width: int, height: int, view, proj, params) -> np.ndarray:
        if self._closed:
            raise WorldClosed("renderer is closed")
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._exec, self.render, state, width, height, view, proj, params)

    def warm_up(self, processes: int | None = None) -> None:
        """Start render processes now (blocking) instead of at the first requests."""
        n = self.size if processes is None else min(processes, self.size)
        ws = []
        try:
            with self._cond:
                for w in self._workers:
                    if len(ws) < n and not w.busy:
                        w.busy = True
                        ws.append(w)
            for w in ws:
                if not w.alive:
                    w.close_conns()
                    w.start(self._plan_msg, self.own_session)
        finally:
            for w in ws:
                self._release(w)

    def pids(self) -> list[int]:
        return [w.proc.pid for w in self._workers if w.alive]

    def close(self) -> None:
        with self._cond:
            if self._closed:
                return
            self._closed = True
            busy = [w.busy for w in self._workers]
            self._cond.notify_all()
        for w, b in zip(self._workers, busy):
            w.stop(kill=b)  # a busy process is killed: the waiting thread sees EOF
        self._exec.shutdown(wait=True)
        for w in self._workers:
            w.close_conns()
        self._finalizer.detach()


def static_layout(plan):
    """What a mirror builds of a house once: the plan without what a frame's state sets (door angles,
    lamps on or off) and without its seed."""
    return dataclasses.replace(plan, seed=0, doors=[dataclasses.replace(d, angle=0.0) for d in plan.doors],
                               lamps=[dataclasses.replace(lp, on=False) for lp in plan.lamps])


class SharedRenderer:
    """One RenderPool for several Worlds of the same house (`World(renderer=...)`). A world's robots
    are mirrored by kind (its first NAO is the mirror's "nao-0" whichever world asks), so the mirror
    holds as many robot bodies as one world has, not as all of them: TinyRenderer transforms every
    body's triangles for every frame, in view or not. Moving bodies are the world's own (named by it).
    The pool's processes start with the first world's plan; a world whose house differs beyond door
    angles and lamps gets a ValueError. Frames queue for the pool's `size` processes."""

    def __init__(self, size: int = 2, name: str = "shared"):
        self.size, self.name = size, name
        self.pool: RenderPool | None = None
        self._layout = None
        self._tags = itertools.count(1)
        self._lock = threading.Lock()  # worlds are built in threads (World.from_file off the loop)

    def view(self, plan) -> "_SharedView":
        layout = static_layout(plan)
        with self._lock:
            if self.pool is None:
                self.pool, self._layout = RenderPool(plan, self.size, name=self.name), layout
            elif layout != self._layout:
                raise ValueError(f"house {plan.name!r} differs from the shared renderer's beyond its doors and lamps")
            return _SharedView(self, f"w{next(self._tags)}")

    def pids(self) -> list[int]:
        return self.pool.pids() if self.pool is not None else []

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()


class _SharedView:
    """What a World holds of a SharedRenderer: RenderPool's calls, its state named for the mirror."""

    def __init__(self, shared: SharedRenderer, tag: str):
        self.shared, self.tag = shared, tag

    @property
    def pool(self) -> RenderPool:
        return self.shared.pool

    @property
    def own_session(self) -> bool:
        return self.pool.own_session

    @own_session.setter
    def own_session(self, value: bool) -> None:
        self.pool.own_session = value

    def named(self, state: SceneState) -> SceneState:
        count: dict[str, int] = {}
        robots = {}
        for name in sorted(state.robots):
            kind = state.robots[name][0]
            robots[f"{kind}-{count.setdefault(kind, 0)}"] = state.robots[name]
            count[kind] += 1
        return dataclasses.replace(state, robots=robots, bodies={f"{self.tag}/{n}": b for n, b in state.bodies.items()})

    def render(self, state: SceneState, *args) -> np.ndarray:
        return self.pool.render(self.named(state), *args)

    async def render_async(self, state: SceneState, *args) -> np.ndarray:
        return await self.pool.render_async(self.named(state), *args)

    def warm_up(self, processes: int | None = None) -> None:
        self.pool.warm_up(processes)

    def pids(self) -> list[int]:
        return self.pool.pids()

    def close(self) -> None:
        """Nothing: the pool is its SharedRenderer's, closed by whoever made it."""
