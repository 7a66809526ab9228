"""One scenario runner under `rapp run rapp`, `hazard-detection`, `two-robots` and the disturbance suite.

A run: a fresh system (embedded XMPP server, Store, Platform) with the RApp published, one Core per
robot with its owner's client subscribed to the Core's task records (ontology/results.py), the home
description uploaded for each owner, each owner's command, and the wait for each command's end as a
typed TaskRecord. The true trajectory of every robot is sampled throughout. What happened is learnt
from those records only, never from the chat's wording or the trace's text.

    run = Run(out, world, rapp_dir, [Owner("nao", api, "owner-nao1", "check the hazards", home=...)])
    await run.run(timeout_s=600)
    run.owners[0].record            # the TaskRecord (None: interrupted, or no end within the timeout)

Interruption (`rapp run ...` under `main_loop`): SIGINT or SIGTERM cancels the run where it waits; the
system is stopped (every agent and process it started ends) and the run returns with `signum` set, so
the scenario writes result.json (`ok: false`, the reason), run.png, chat and trace with what is known,
then raises RunInterrupted (a loop over runs stops too) and the command exits 128 + the signal.
"""
from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
import signal
import sys
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ontology.manifest import load_manifest
from ontology.results import ReportRecord, TaskRecord
from xmpp_server.link import LinkFaults
from robots.gridmap import build_grid_map

from .home_setup import DOOR_OPEN_DEG, has_layout, home_map
from .progress import follow
from .recording import Recording
from .system import RappSystem, RobotHandle, wait_until

SAMPLE_S = 0.2  # simulation seconds between samples of the true trajectory


class RunInterrupted(BaseException):
    """A signal ended a run after its result was written (a BaseException: loops over runs stop too)."""

    def __init__(self, result: dict, signum: int):
        super().__init__(f"interrupted by {signal.Signals(signum).name}")
        self.result, self.signum = result, signum


@dataclass
class Owner:
    """One robot of a run, its owner and the owner's command (None: the owner gives it by voice)."""

    kind: str
    api: Any  # scenarios.recorder.RecordingAPI around the robot's RobotAPI
    user: str
    command: str | None
    home: tuple | None = None  # (HomeInfo, png bytes, yaml text): uploaded for the owner before the run
    core_kw: dict = field(default_factory=dict)
    deliver: Callable[["Owner"], Awaitable[None]] | None = None  # how the command is given (default: chat)
    link: LinkFaults | None = None  # the robot's connection to the server (xmpp_server/link.py); None: perfect
    command_at: float | None = None  # the simulated time to give the command at (a re-simulation's; None: at once)
    # filled in by the run
    handle: RobotHandle | None = None
    record: TaskRecord | None = None
    chat: list[str] = field(default_factory=list)
    transcript: list[str] = field(default_factory=list)  # the chat with each line's sender (chat.txt)
    wall_s: float = 0.0
    given_at: float | None = None  # the simulated time the command was given (result.json's command_sim_s)
    told_from: int = 0  # the owner client's ends and chat before the command: not this run's
    chat_from: int = 0

    @property
    def reports(self) -> list[ReportRecord]:
        """The RApp's reports: the end record's, else (interrupted, or earliest left out) as they came."""
        if self.record is not None and not self.record.reports_omitted:
            return list(self.record.reports)
        return [r.report for r in self.handle.user.reported] if self.handle else []


class Run:
    def __init__(self, out: Path, world, rapp: Path, owners: list[Owner], *, settings=None,
                 platform_kw: dict | None = None, record: bool = True, frames: bool = True, grid=None):
        """`record`: the run's recording (scenarios/recording.py: message bodies, packages, robot.jsonl,
        then run.mcap by finish_recording()); `frames`: with the camera's frames; `grid`: the map in it."""
        self.out, self.world, self.rapp, self.owners = Path(out), world, Path(rapp), owners
        self.settings, self.platform_kw = settings, platform_kw or {}
        self.recording = Recording(self.out, world, {o.kind: o.api for o in owners}, grid, frames) if record else None
        self.trace = self.out / "trace.jsonl"
        self.name, self.keywords = "", []
        self.trajectories: dict[str, list[list[float]]] = {o.kind: [] for o in owners}  # [t, x, y, theta]
        self.truth_at_start = None  # robots.GroundTruth when the commands were given
        self.sim_s = self.wall_s = 0.0
        self.signum: int | None = None
        self.failure = ""  # why the run did not get every end it waited for ("" if it did)
        self.system: RappSystem | None = None

    @property
    def interrupted(self) -> str:
        return f"interrupted by {signal.Signals(self.signum).name}" if self.signum else ""

    async def run(self, timeout_s: float, *, show: dict | None = None,
                  before: Callable[["Run"], Awaitable[None]] | None = None,
                  during: Callable[["Run"], Awaitable[None]] | None = None,
                  after: Callable[["Run"], Awaitable[None]] | None = None,
                  accept: Callable[[TaskRecord], bool] | None = None) -> "Run":
        """`show`: follow the trace's progress (scenarios.progress.follow's keywords); `before`: once
        every Core listens, before the commands; `during`: beside the task, cancelled at its end;
        `after`: once every end is in (or the run was interrupted), before the system stops;
        `accept`: which ends end the wait (default: any)."""
        self.out.mkdir(parents=True, exist_ok=True)
        self.trace.unlink(missing_ok=True)
        shutil.rmtree(self.out / "system", ignore_errors=True)  # a fresh Store and XMPP accounts
        samplers = [asyncio.create_task(self._sample(o)) for o in self.owners]
        side: asyncio.Task | None = None
        linked = any(o.link is not None for o in self.owners)  # then no agent takes the in-process shortcut
        self.system = system = RappSystem(self.out / "system", settings=self.settings, trace_file=self.trace,
                                          platform_kw=self.platform_kw, force_xmpp=True if linked else None)
        if self.recording is not None:
            for stale in ("run.mcap", "robot.jsonl"):
                (self.out / stale).unlink(missing_ok=True)
            shutil.rmtree(self.out / "packages", ignore_errors=True)
            self.recording.begin()
            self.recording.start()
        try:
            await system.start()
            await self._publish()
            if show is not None:
                follower = asyncio.create_task(follow(self.trace, **show))
                system.on_stop(follower.cancel)
            for owner in self.owners:
                await self._add(owner)
            if before is not None:
                await before(self)
            self.truth_at_start = self.world.ground_truth()
            sim0, wall0 = self.world.time, time.monotonic()
            for owner in self.owners:
                owner.told_from = len(owner.handle.user.ended)
                owner.chat_from = len(owner.handle.user.received)
                if owner.command_at is not None and owner.command_at > self.world.time:
                    await self.world.sleep(owner.command_at - self.world.time)  # as late as in the recorded run
                owner.given_at = round(self.world.time, 3)
                await (owner.deliver or _chat)(owner)
            side = asyncio.create_task(during(self)) if during is not None else None
            ends = await asyncio.gather(*(self._wait(o, timeout_s, accept) for o in self.owners))
            self.failure = next((e for e in ends if e), "")
            self.sim_s, self.wall_s = self.world.time - sim0, time.monotonic() - wall0
            if after is not None:
                await after(self)
        except asyncio.CancelledError:
            if _STATE.signum is None:
                raise
            asyncio.current_task().uncancel()
            self.signum = _STATE.signum
            self.failure = self.interrupted
            if self.truth_at_start is not None:
                self.sim_s, self.wall_s = self.world.time - sim0, time.monotonic() - wall0
            with contextlib.suppress(Exception):
                if after is not None:
                    await asyncio.wait_for(after(self), 20.0)
        finally:
            if side is not None:
                side.cancel()
            for owner in self.owners:  # the chat as it was when the run ended
                if owner.handle is not None:
                    owner.chat = owner.handle.user.texts()[owner.chat_from:]
                    owner.transcript = owner.handle.user.transcript(owner.chat_from, owner.handle.core.address)
            with saving():  # a signal now does not cut the stopping short
                await system.stop()
            for task in samplers:
                task.cancel()
            if self.recording is not None:
                self.recording.stop()
        if _STATE.signum is not None:  # also when it came while the system stopped
            self.signum, self.failure = _STATE.signum, self.interrupted
        return self

    async def _publish(self) -> None:
        system = self.system
        if self.rapp.is_dir():
            self.name = (await system.publish(self.rapp)).split()[0]
            self.keywords = load_manifest(self.rapp).keywords
            return
        # a built package: published as it is (its Cores then accept it unsigned)
        from agents.store_client import publish_package
        from ontology.package import read_package
        from ontology.store import RegisterOwner

        data = self.rapp.read_bytes()
        pkg = read_package(data)
        self.name, self.keywords = pkg.manifest.name, pkg.manifest.keywords
        await system.publisher.request(system.store.address, RegisterOwner(owner="developer",
                                                                           password="developer-secret"))
        await publish_package(system.publisher, system.store.address, "developer", "developer-secret", data)
        for owner in self.owners:
            owner.core_kw = {"require_signature": False, "trusted_keys": None, **owner.core_kw}

    async def _add(self, owner: Owner) -> None:
        from .home_setup import upload_home

        if owner.home is not None:  # the owner's home description, as the Platform keeps it
            upload_home(self.system.platform.state, owner.user, *owner.home)
        owner.handle = handle = await self.system.add_robot(owner.kind, api=owner.api, user=owner.user,
                                                            link=owner.link, **owner.core_kw)
        await handle.user.watch_tasks(handle.core.address)
        await wait_until(lambda: listening(handle.core), 30, f"Core of {owner.kind} listening", interval=0.05)

    async def _wait(self, owner: Owner, timeout_s: float, accept) -> str:
        t0 = time.monotonic()
        try:
            owner.record = await owner.handle.user.task_end(timeout_s, owner.told_from, accept or (lambda r: True))
            return ""
        except asyncio.TimeoutError:
            where = standing(owner.handle.core)
            return f"{owner.kind}: no end within {timeout_s:g} s" + (f": {where}" if where else "")
        finally:
            owner.wall_s = time.monotonic() - t0

    async def _sample(self, owner: Owner) -> None:
        """The robot's true pose through the whole run (simulation time), for truth and plot."""
        into, robot = self.trajectories[owner.kind], owner.api.robot
        while True:
            x, y, theta = robot.pose[:3]
            into.append([round(self.world.time, 2), round(x, 3), round(y, 3), round(theta, 4)])
            await self.world.sleep(SAMPLE_S, drive=False)  # observe; never run the world ahead

    async def finish_recording(self) -> Path | None:
        """run.mcap from the run folder (after result.json: its metadata come from there)."""
        return await self.recording.finish() if self.recording is not None else None

    # -- what the scenarios write ---------------------------------------------------------------
    def truth(self, kind: str | None = None) -> dict:
        """The world's truth for scoring: doors (angle, open) and lamps when the commands were given,
        those that changed by the end, and the true trajectory ([t, x, y, theta] every 0.2 s sim)."""
        start = self.truth_at_start or self.world.ground_truth()
        end = self.world.ground_truth()
        doors = {d: {"angle_deg": round(a, 2), "open": a > DOOR_OPEN_DEG} for d, a in start.doors.items()}
        out = {"seed": self.world.plan.seed, "doors": doors, "lamps": {lp: {"on": on} for lp, on in start.lamps.items()}}
        changed = {d: round(a, 2) for d, a in end.doors.items() if abs(a - start.doors.get(d, a)) > 0.5}
        if changed:
            out["doors_changed"] = changed  # a disturbance moved them during the run (angle at the end)
        kinds = [kind] if kind else list(self.trajectories)
        out["trajectory"] = self.trajectories[kinds[0]] if kind or len(kinds) == 1 else \
            {k: self.trajectories[k] for k in kinds}
        return out

    def ok(self, owner: Owner) -> bool:
        return owner.record is not None and owner.record.ok and not self.signum

    def reason(self, owner: Owner) -> str:
        if self.signum:
            n = len(owner.reports)
            return f"{self.interrupted} after {self.wall_s:.0f} s" + (
                f" (the RApp had reported {n} time{'' if n == 1 else 's'})" if n else "")
        if owner.record is None:
            return self.failure or "no end"
        return owner.record.reason

    def end_text(self, owner: Owner) -> str:
        """What the owner was told at the end (or why there is no end)."""
        if owner.record is not None and not self.signum:
            return owner.record.told or owner.record.reason
        return self.reason(owner)


def standing(core) -> str:
    """Where a run that did not end stands, from its Core: the Core's state, the RApp's state and its last
    report, what the Core waits for (a stop's "resume", a way past an obstacle)."""
    state = core.supervisor.behaviour.current if core.supervisor is not None else None
    parts = [f"the Core in {state}"] if state else []
    d = core.dynamic
    if d is not None:
        parts.append(f"{d.rapp} {d.state}, " + (f"last report {d.reports[-1].text[:100]!r}" if d.reports
                                                else "no report yet"))
    waiting = core.strategies.waiting_for()
    return "; ".join(parts + ([f"waiting for {waiting}"] if waiting else []))


def listening(core) -> bool:
    return bool(core.vocabulary) and core.listening


async def _chat(owner: Owner) -> None:
    await owner.handle.user.say(owner.handle.core.address, owner.command)


def plot_grid(world, house: str):
    """The map drawn under a run's plot: the home's map where the house has a hazard layout."""
    name = Path(house).stem
    return home_map(world, name) if has_layout(name, world) else build_grid_map(world.plan)


def files_written(out: Path) -> str:
    """Every file and folder a run wrote in `out`, for the closing summary."""
    parts = []
    for p in sorted(Path(out).iterdir(), key=lambda p: (p.is_dir(), p.name)):
        if p.is_dir():
            n = sum(1 for f in p.rglob("*") if f.is_file())
            parts.append(f"{p.name}/ ({n} file{'' if n == 1 else 's'})")
        else:
            parts.append(p.name)
    return ", ".join(parts)


# -- interruption ---------------------------------------------------------------------------------
@dataclass
class _Interrupts:
    signum: int | None = None
    count: int = 0
    saving: int = 0  # > 0: results being written; a signal then waits for them


_STATE = _Interrupts()


@contextlib.contextmanager
def saving():
    """Writing a run's files: a signal now lets them be written, then the run raises RunInterrupted."""
    _STATE.saving += 1
    try:
        yield
    finally:
        _STATE.saving -= 1


def interrupted_by() -> int | None:
    return _STATE.signum


def check_interrupted(result: dict) -> None:
    """Raise RunInterrupted once a run interrupted by a signal has written `result`."""
    if _STATE.signum is not None:
        raise RunInterrupted(result, _STATE.signum)


def main_loop(coro) -> Any:
    """asyncio.run(coro) for a `rapp run` command: SIGINT and SIGTERM interrupt the run (see the
    module's doc); a second signal says the files are being written, a third ends the process at once."""
    async def main():
        loop, task = asyncio.get_running_loop(), asyncio.current_task()

        def on_signal(signum: int) -> None:
            _STATE.count += 1
            if _STATE.count == 1:
                _STATE.signum = signum
                print(f"\n[run] {signal.Signals(signum).name}: stopping the run and writing what is known "
                      "(result.json, run.png, chat, trace)", file=sys.stderr, flush=True)
                if not _STATE.saving:
                    task.cancel()
            elif _STATE.count == 2:
                print("[run] still stopping the system and writing the files; once more to quit at once",
                      file=sys.stderr, flush=True)
            else:
                os._exit(128 + signum)

        for s in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(s, on_signal, s)
        try:
            return await coro
        except asyncio.CancelledError:
            if _STATE.signum is None:
                raise
            raise RunInterrupted({}, _STATE.signum) from None  # before a run began: nothing to write
        finally:
            for s in (signal.SIGINT, signal.SIGTERM):
                loop.remove_signal_handler(s)

    _STATE.signum, _STATE.count, _STATE.saving = None, 0, 0
    return asyncio.run(main())


def add_recording_options(parser, replay: bool = True) -> None:
    """--no-record, --no-frames and (`replay`) --replay, --tolerance: the recording options every
    `rapp run` scenario that records takes (docs/recordings.md)."""
    parser.add_argument("--no-record", action="store_true", help="no recording: no message bodies, robot.jsonl, "
                                                                  "packages/ nor run.mcap (docs/recordings.md)")
    parser.add_argument("--no-frames", action="store_true", help="a recording without the camera's frames")
    if not replay:
        return
    parser.add_argument("--replay", metavar="RUN_DIR", help="re-simulate a recorded run (its robot, house, seed, "
                        "realism and disturbances, and its command at its simulated time), then compare reports "
                        "and trajectory with it (docs/recordings.md)")
    parser.add_argument("--tolerance", type=float, default=None, metavar="M",
                        help="--replay: how far (m) the trajectories may be apart (default 0.25)")
