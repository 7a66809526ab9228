"""Process pool for the Platform's CPU-bound services (vision, hazard checks, speech, path planning).

Threads of one Python process share one GIL: OpenCV and NumPy release it only inside their C loops,
so services run with `asyncio.to_thread` stall each other and the agent's event loop (XMPP parsing,
JSON) on the same core. `ServicePool` runs them in worker processes instead:

- `size` workers (default: os.cpu_count()), started ahead by `start()`, forked from a fork server of
  its own (one per Platform process, a plain child that has imported the services once): a worker
  starts in tens of ms, the Platform's threaded process never forks, and unlike multiprocessing's
  fork server, the parent's __main__ is never run again in a worker;
- one thread per worker in the Platform takes the jobs routed to its worker (the least loaded one;
  a plan preferably to the worker that already has that map's cost maps), writes the request down
  the worker's pipe and waits for its answer, so the event loop only awaits a future;
- state stays in the Platform: a call takes the little it needs with it (a user's learned objects,
  a noise profile, the live obstacle marks) and gives back what it stored (a new noise profile), as
  its row of the service table declares (agents/services/registry.py: reads, writes; state_parts.py).
  A map is the exception: each worker caches it under its content hash (`GridMap.content_key`),
  together with its cost maps and landmark tables, so a 4 MB grid crosses the pipe once per worker;
  a worker that no longer holds it answers "need-map" and gets it again;
- a worker that dies during a call fails that call with `WorkerLost` (a clear reason) and is
  replaced; a worker found dead between calls is replaced before the next one;
- `close()` kills the workers and waits for them (no orphan outlives the Platform).

    pool = ServicePool(); pool.start()
    reply = await pool.run("qr_detection", request, ServiceContext(user, state))
    pool.close()
"""
from __future__ import annotations

import asyncio
import os
import queue
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import traceback
from collections import Counter, OrderedDict
from dataclasses import dataclass, field
from multiprocessing.connection import Client, Listener
from pathlib import Path
from typing import Any

import numpy as np

from ontology.errors import ErrorCode

from .errors import ServiceError

START_TIMEOUT_S = 60.0  # for a worker to fork and say it is ready (a loaded machine)
# base maps a worker keeps (with their cost maps, graphs and landmark tables: ~40 bytes a cell),
# counted in cells: a few large maps or hundreds of homes of a fleet
MAP_CELLS_PER_WORKER = 16_000_000
OVERLAYS_PER_WORKER = 8  # maps with obstacle marks drawn in


class WorkerLost(ServiceError):
    """The worker process running a call died (killed, out of memory, a crash in native code)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason, ErrorCode.SERVICE_ERROR)


class PoolClosed(ServiceError):
    def __init__(self) -> None:
        super().__init__("the Platform's service pool is stopping", ErrorCode.UNAVAILABLE)


# ================================================================================ worker side
@dataclass
class Job:
    service: str
    request: Any  # the registered request model (pickled)
    user: str
    stores: dict[str, Any] = field(default_factory=dict)  # named stores the call reads (ServiceState.store)
    map_key: str = ""  # a service on a map (ServiceSpec.on_map: plan_path_2d): the map's content hash
    map_data: tuple | None = None  # (map_id, packed grid, shape, resolution, origin, shared): sent on a miss
    marks: tuple = ()  # the caller's live obstacle marks on that map


def _worker_main(conn, home: str) -> None:
    """A worker's loop: ("call", Job) -> ("ok", reply, stores) | ("error", reason, code) | ("need-map",)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the Platform's to handle; it kills us
    import cv2

    from . import SERVICES
    from .context import ServiceContext, ServiceState
    from .maps import GridMap
    from .obstacles import OverlayMap, disc_mask
    from .state_parts import travel

    cv2.setNumThreads(1)  # one worker per core already
    # in the pool's private directory: removed with it (a worker dies by SIGKILL, it cannot clean up)
    state = ServiceState(work_dir=Path(tempfile.mkdtemp(prefix="worker-", dir=home)))
    maps: OrderedDict[str, GridMap] = OrderedDict()
    overlays: OrderedDict[tuple, GridMap] = OrderedDict()

    def base_map(job: Job) -> GridMap | None:
        if job.map_data is not None:
            map_id, packed, shape, res, origin, shared = job.map_data
            blocked = np.unpackbits(packed, count=shape[0] * shape[1]).reshape(shape).astype(bool)
            maps[job.map_key] = GridMap(map_id, blocked, res, origin, shared)
            while len(maps) > 1 and sum(g.blocked.size for g in maps.values()) > MAP_CELLS_PER_WORKER:
                maps.popitem(last=False)
        m = maps.get(job.map_key)
        if m is not None:
            maps.move_to_end(job.map_key)
        return m

    def overlay(m: GridMap, job: Job) -> GridMap:
        if not job.marks:
            return m
        key = (job.map_key, tuple(k.shape for k in job.marks))
        over = overlays.get(key)
        if over is None:
            over = OverlayMap(m.map_id, m.blocked | disc_mask(m, job.marks), m.resolution, m.origin, m.shared,
                              base=m, marks=job.marks)
            overlays[key] = over
            while len(overlays) > OVERLAYS_PER_WORKER:
                overlays.popitem(last=False)
        overlays.move_to_end(key)
        return over

    def serve(job: Job) -> tuple:
        spec = SERVICES[job.service]
        if job.map_key:
            m = base_map(job)
            if m is None:
                return ("need-map",)
            return ("ok", spec.on_map(job.request, m, lambda base: overlay(base, job)), {})
        state.replace_stores({name: travel(name).unpack(part) for name, part in job.stores.items()})
        reply = spec.run(job.request, ServiceContext(user=job.user, state=state))
        return ("ok", reply, {name: travel(name).pack(store) for name, store in state.stores_named(spec.writes).items()})

    conn.send(("ready", os.getpid()))
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):  # the Platform closed the pipe or died
            return
        if msg[0] != "call":
            return
        try:
            out = serve(msg[1])
        except ServiceError as e:
            out = ("error", e.reason, e.code)
        except Exception as e:  # noqa: BLE001 - any failure of a service is the caller's answer
            traceback.print_exc()
            out = ("error", f"{type(e).__name__}: {e}", ErrorCode.SERVICE_ERROR)
        try:
            conn.send(out)
        except (EOFError, OSError):
            return


def _taken(spec, req, ctx) -> dict[str, Any]:
    """The part of the Platform's state a pooled call reads (ServiceSpec.reads: the caller's own entries)."""
    taken = {name: read(req, ctx) for name, read in spec.reads.items()}
    return {name: part for name, part in taken.items() if part is not None}


def _merge(ctx, given: dict[str, Any]) -> None:
    """What a pooled call stored (ServiceSpec.writes), into the Platform's state (and its saved data)."""
    from .state_parts import merge

    for name, part in given.items():
        merge(ctx, name, part)


# ================================================================================ Platform side
# The fork server: a plain `python -c` child (multiprocessing's would re-run the parent's __main__
# in every worker) that imports the services once, then forks one worker per request; a worker
# connects back to its pool's socket. BLAS/OpenMP stay single-threaded in it: no thread exists
# when it forks, and one worker per core is parallel enough.
_BOOT = """
import sys
sys.path.insert(0, {root!r})
from agents.services.pool import _fork_server_main
_fork_server_main()
"""
_SERVER = None
_SERVER_LOCK = threading.Lock()


def _fork_server_main() -> None:
    import agents.services  # noqa: F401 - what every worker needs, imported once

    signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # workers are reaped by the kernel
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for line in sys.stdin:  # "<pool address> <authkey hex>" per worker; EOF: the parent is gone
        address, key = line.split()
        pid = os.fork()
        if pid == 0:
            code = 0
            try:
                signal.signal(signal.SIGCHLD, signal.SIG_DFL)
                null = os.open(os.devnull, os.O_RDWR)
                os.dup2(null, 0)
                os.dup2(null, 1)
                _worker_main(Client(address, authkey=bytes.fromhex(key)), os.path.dirname(address))
            except BaseException:  # noqa: BLE001 - a worker never returns into the server's loop
                traceback.print_exc()
                code = 1
            finally:
                os._exit(code)
        sys.stdout.write(f"{pid}\n")
        sys.stdout.flush()


def _fork_worker(address: str, key: bytes) -> int:
    """Ask this process's fork server (started at first use) for a worker; its pid."""
    global _SERVER
    with _SERVER_LOCK:
        for attempt in (0, 1):
            if _SERVER is None or _SERVER.poll() is not None:
                root = str(Path(__file__).resolve().parents[2])
                env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
                _SERVER = subprocess.Popen([sys.executable, "-c", _BOOT.format(root=root)], stdin=subprocess.PIPE,
                                           stdout=subprocess.PIPE, env=env, text=True, close_fds=True)
            try:
                _SERVER.stdin.write(f"{address} {key.hex()}\n")
                _SERVER.stdin.flush()
                line = _SERVER.stdout.readline()
                if line.strip():
                    return int(line)
            except (BrokenPipeError, OSError, ValueError):
                pass
            _SERVER.kill()  # broken: a fresh one next
            _SERVER.wait()
            _SERVER = None
        raise WorkerLost("the service pool's fork server failed to start a worker")


class _Worker:
    """One worker process and the thread in the Platform that feeds it."""

    def __init__(self, pool: "ServicePool", index: int):
        self.pool, self.index = pool, index
        self.conn = None
        self.pid: int | None = None
        self.busy = False
        self.queued = 0  # jobs waiting in `jobs`
        self.jobs: queue.Queue = queue.Queue()
        self.maps: set[str] = set()  # content keys this worker was sent (a hint: "need-map" corrects it)
        self.affine: set[str] = set()  # content keys whose plans were routed here
        self.thread = threading.Thread(target=self._loop, name=f"{pool.name}-pool-{index}", daemon=True)

    def _spawn(self) -> None:
        self.conn, self.pid = self.pool.connect_worker(self.index)
        self.maps = set()
        self.pool.worker_started(self.index)

    def alive(self) -> bool:
        """An idle worker never writes: a readable pipe is its end (EOF)."""
        if self.conn is None:
            return False
        try:
            return not self.conn.poll(0)
        except (EOFError, OSError):
            return False

    def reap(self) -> str:
        """Close our end and make sure the process is gone (the fork server reaps it)."""
        conn, self.conn = self.conn, None
        if conn is not None:
            conn.close()
        if self.pid is not None:
            _kill(self.pid)
        return "the process ended"

    def _loop(self) -> None:
        pool = self.pool
        try:
            self._spawn()
        except Exception as e:  # noqa: BLE001 - retried at the first call
            pool.note_failure(f"worker {self.index} failed to start: {e}")
        while True:
            item = self.jobs.get()
            if item is None or pool.closed:
                break
            job, fut, loop, grid = item
            with pool.counts_lock:
                self.queued -= 1
                self.busy = not fut.done()
            if fut.done():  # the caller gave up (cancelled) while the job waited
                continue
            try:
                result = self._call(job, grid)
            except BaseException as e:  # noqa: BLE001 - delivered to the caller
                result = e
            finally:
                self.busy = False
            loop.call_soon_threadsafe(_deliver, fut, result)
        self.reap()

    def _call(self, job: Job, grid) -> tuple:
        if not self.alive():  # died idle (or never started): replace first
            if self.conn is not None:
                self.pool.note_failure(f"worker {self.index} (pid {self.pid}) found dead: {self.reap()}")
            if self.pool.closed:
                raise PoolClosed()
            self._spawn()
        pid = self.pid
        try:
            if job.map_key and job.map_key not in self.maps:
                job.map_data = _map_payload(grid)
                self.pool.map_sends += 1
            out = self._send(job)
            if out[0] == "need-map":  # evicted there since
                job.map_data = _map_payload(grid)
                self.pool.map_sends += 1
                out = self._send(job)
        except (EOFError, OSError) as e:
            if self.pool.closed:
                self.reap()
                raise PoolClosed() from None
            how = self.reap()
            self.pool.note_failure(f"worker {self.index} (pid {pid}) died during {job.service}: {how}")
            try:
                self._spawn()
            except Exception as err:  # noqa: BLE001 - tried again at the next call
                self.pool.note_failure(f"worker {self.index} failed to restart: {err}")
            raise WorkerLost(f"the service worker process (pid {pid}) running {job.service} died ({how}); "
                             "the Platform has replaced it: send the request again") from e
        if job.map_key:
            self.maps.add(job.map_key)
        self.pool.calls_by_pid[pid] += 1
        return out

    def _send(self, job: Job) -> tuple:
        self.conn.send(("call", job))
        return self.conn.recv()


def _map_payload(m) -> tuple:
    if m is None:
        raise ServiceError("the map of this plan is no longer on the Platform", ErrorCode.NOT_FOUND)
    return (m.map_id, np.packbits(m.blocked), m.blocked.shape, m.resolution, tuple(m.origin), m.shared)


def _kill(pid: int) -> None:
    try:
        os.kill(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def _deliver(fut: asyncio.Future, result) -> None:
    if fut.done():
        return
    if isinstance(result, BaseException):
        fut.set_exception(result)
    else:
        fut.set_result(result)


class ServicePool:
    """Worker processes for the CPU-bound services (ServiceSpec.pooled); see the module docstring."""

    def __init__(self, size: int | None = None, *, name: str = "platform"):
        self.size = max(1, int(size or os.cpu_count() or 1))
        self.name = name
        self.closed = False
        self._workers = [_Worker(self, i) for i in range(self.size)]
        self.counts_lock = threading.Lock()  # the workers' counts: queued, busy, starts
        self._accept_lock = threading.Lock()
        self._key = secrets.token_bytes(16)
        # workers connect here (a socket file in a fresh private directory)
        self._sockdir = tempfile.mkdtemp(prefix="rapp-pool-")
        self._listener = Listener(os.path.join(self._sockdir, "pool"), family="AF_UNIX", authkey=self._key)
        # accept() has no timeout of its own: set on the socket multiprocessing keeps private
        self._listener._listener._socket.settimeout(START_TIMEOUT_S)  # noqa: SLF001
        self.calls_by_pid: Counter[int] = Counter()  # which process served how many calls
        self.failures: list[str] = []  # worker deaths and failed starts, newest last
        self.restarts = 0
        self.map_sends = 0  # grids sent to a worker (once per worker and map unless evicted)
        self._started_once: set[int] = set()
        self._ready = threading.Event()

    def start(self) -> None:
        """Start the workers (each from its own thread: the caller does not wait for them)."""
        for w in self._workers:
            w.thread.start()

    def wait_ready(self, timeout: float = START_TIMEOUT_S) -> bool:
        """Block until every worker has started once (tests, benchmarks)."""
        return self._ready.wait(timeout)

    def connect_worker(self, index: int):
        """Fork worker `index` and take its connection: (connection, its pid once it said ready)."""
        with self._accept_lock:  # one connection expected at a time on the pool's socket
            pid = _fork_worker(self._listener.address, self._key)
            try:
                conn = self._listener.accept()
                if not conn.poll(START_TIMEOUT_S):
                    raise OSError("no ready message")
                kind, ready_pid = conn.recv()
            except OSError as e:
                _kill(pid)
                raise WorkerLost(f"service worker {index} did not start within {START_TIMEOUT_S:.0f} s: {e}") \
                    from None
        return conn, ready_pid

    def worker_started(self, index: int) -> None:
        with self.counts_lock:
            if index in self._started_once:
                self.restarts += 1
            self._started_once.add(index)
            if len(self._started_once) == self.size:
                self._ready.set()

    def note_failure(self, text: str) -> None:
        self.failures.append(text)
        del self.failures[:-50]

    @property
    def pids(self) -> list[int]:
        """The live workers' process ids."""
        return [w.pid for w in self._workers if w.conn is not None and w.pid is not None]

    def busy_pids(self) -> list[int]:
        return [w.pid for w in self._workers if w.busy and w.pid is not None]

    @property
    def outstanding(self) -> int:
        """Calls queued or running."""
        return sum(w.queued + w.busy for w in self._workers)

    def _pick(self, map_key: str) -> _Worker:
        """The least loaded worker; for a plan, the one that has the map's cost maps and landmark
        tables unless it is busier than that by more than one call (then another builds them too)."""
        with self.counts_lock:
            def load(w: _Worker) -> int:
                return w.queued + w.busy
            best = min(self._workers, key=load)
            if map_key:
                holders = [w for w in self._workers if map_key in w.affine]
                if holders and load(min(holders, key=load)) <= load(best) + 1:
                    best = min(holders, key=load)
                best.affine.add(map_key)
            best.queued += 1
            return best

    async def run(self, service: str, req, ctx):
        """The service's reply, computed in a worker process (ServiceError as the service raised it)."""
        if self.closed:
            raise PoolClosed()
        from .registry import SERVICES

        spec = SERVICES[service]
        job = Job(service, req, ctx.user, stores=_taken(spec, req, ctx))
        m = None
        if spec.on_map is not None:
            m = ctx.state.maps.get(ctx.user, req.map_id)
            if m is None:  # answered here: nothing to compute
                return spec.on_map(req, None, lambda base: base)
            if req.use_obstacles:
                job.marks = tuple(sorted(ctx.state.obstacles.marks(ctx.user, m.map_id), key=lambda k: k.shape))
            known = m.peek(("content-key",))
            job.map_key = known or await asyncio.to_thread(m.content_key)  # ~ms for a large grid
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        self._pick(job.map_key).jobs.put((job, fut, loop, m))
        out = await fut
        if out[0] == "error":
            raise ServiceError(out[1], out[2])
        if out[2]:  # written through to the Platform's saved data: off the event loop
            await asyncio.to_thread(_merge, ctx, out[2])
        return out[1]

    def close(self) -> None:
        """Kill the workers and wait for them (blocking: call from a thread)."""
        if self.closed:
            return
        self.closed = True
        for w in self._workers:
            if w.pid is not None:
                _kill(w.pid)  # a thread waiting on its pipe reads EOF
        for w in self._workers:
            w.jobs.put(None)
        for w in self._workers:
            if w.thread.is_alive():
                w.thread.join(10)
            w.reap()
        self._listener.close()
        shutil.rmtree(self._sockdir, ignore_errors=True)
        for w in self._workers:  # calls still queued: told, not left waiting
            while True:
                try:
                    item = w.jobs.get_nowait()
                except queue.Empty:
                    break
                if item is not None:
                    item[2].call_soon_threadsafe(_deliver, item[1], PoolClosed())
