"""Scheduled tasks: the Core starts a RApp at a time the owner named (paper 000 sec. 7: the robot
searches the house "upon request from the user or executing a scheduled task").

The owner says or writes it ("check the hazards every day at 22:00", "... in ten minutes",
"cancel the evening check", "what is scheduled?"); the Platform's interpretation finds the RApp
and the time as said (agents/services/interpretation.py); the Core resolves the time against its
own clock and keeps the schedule here, in its data directory (`schedules.db`, SQLite, schema
versions by agents/schema.py), so a restart of the Core keeps it.

What is refused, with the reason told to the owner (and a `schedule-refused` trace record):
  - a time that has passed ("today at 7:00" said at 8:00, a date gone) or more than a year ahead;
  - a RApp the Store does not offer for this robot;
  - a clash: each schedule holds the robot from its start for its RApp's time limit (the most its
    task may take, from the manifest); a schedule whose span overlaps another's is refused;
  - the robot busy: a task running now may hold the robot until its start + its time limit.
At its time a schedule enters fig. 5 as a command the Core knows (s3 -> s4a, as an isolated
keyword does) and runs s5, s6, s8, s10 like any task; the trace's `schedule-due` and `handoff`
records and the task's TaskRecord carry trigger "scheduled". A daily schedule moves to its next day
as it comes due; a once schedule is forgotten when it starts. When the robot cannot start it at its
time (a commanded task still running, the Core stopped) it starts as soon as it can within LATE_S;
later than that it is missed, and the owner is told.

Clocks: `WallClock` (the machine's); `WorldClock` (a simulated robot's: a date and time at the
world's time 0 plus the world's simulated time, robots/simclock.py). In a scenario the world runs
only when something drives it; a WorldClock with `fast_forward` drives it to the next schedule's
time while the Core is idle in s3 (a 22:00 check said at 21:55 starts after seconds, not minutes).
"""
from __future__ import annotations

import asyncio
import json
import logging
import math
import sqlite3
import threading
import time
from dataclasses import dataclass
from datetime import date, datetime, timedelta, tzinfo
from pathlib import Path
from typing import Awaitable, Callable, Protocol

from ontology import store as S
from ontology.results import ScheduleChanged, ScheduleEvent, ScheduleRecord
from ontology.services.interpretation import ScheduleAction, ScheduleRequest, When
from ontology.trace import StructureEvent

from .errors import RequestError
from .schema import open_migrated

log = logging.getLogger("rapp.scheduler")
LATE_S = 600.0  # a schedule starts up to this late (robot busy, Core stopped); later it is missed
MAX_AHEAD_S = 366 * 86400.0
DAY_S = 86400.0
PARTS = {"morning": (5, 12), "afternoon": (12, 18), "evening": (17, 24), "night": (21, 29)}  # hours (29: 5 am)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS schedules (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    robot_id TEXT NOT NULL,
    rapp TEXT NOT NULL,
    params TEXT NOT NULL,
    command TEXT NOT NULL,
    kind TEXT NOT NULL CHECK (kind IN ('once', 'daily')),
    time_of_day TEXT,
    due REAL NOT NULL,
    window_s REAL NOT NULL,
    created REAL NOT NULL
)
"""
MIGRATIONS: tuple = (_SCHEMA,)


class ScheduleRefused(Exception):
    """A schedule the Core cannot keep; the message is what the owner is told."""


class ScheduleDeclined(Exception):
    """A schedule the owner did not confirm (agents/core_confirm.py): `told`, what the owner is told;
    the message, the reason recorded."""

    def __init__(self, reason: str, told: str):
        super().__init__(reason)
        self.told = told


Confirm = Callable[[str], Awaitable[None]]  # asks the owner about the words heard; ScheduleDeclined: not kept


@dataclass
class ScheduledStart:
    """A schedule come due: what s3 takes from the command queue (then s4a knows its RApp)."""

    schedule: ScheduleRecord
    due: float  # the occurrence's time (epoch s)


# -- clocks ------------------------------------------------------------------------------------------
class Clock(Protocol):
    tz: tzinfo

    def now(self) -> float:
        """Seconds since the epoch, as this robot's clock reads."""

    async def sleep_until(self, t: float, idle) -> None:
        """Return once now() >= t; `idle()` says whether the Core is idle (a simulated clock may run ahead)."""


class WallClock:
    def __init__(self):
        self.tz = datetime.now().astimezone().tzinfo

    def now(self) -> float:
        return time.time()

    async def sleep_until(self, t: float, idle) -> None:
        while (left := t - time.time()) > 0:  # in pieces: the machine's clock may be set meanwhile
            await asyncio.sleep(min(left, 30.0))


class WorldClock:
    """A simulated robot's clock: `start` (an aware datetime) at the world's present time, then the
    world's simulated seconds. `fast_forward`: while the Core is idle, drive the world to the next
    schedule's time (in pieces of STEP_S, so a command that comes meanwhile stops it within one)."""

    STEP_S = 5.0

    def __init__(self, world, start: datetime, fast_forward: bool = False):
        if start.tzinfo is None:
            start = start.astimezone()
        self.world, self.tz, self.fast_forward = world, start.tzinfo, fast_forward
        self.epoch = start.timestamp() - world.time

    def now(self) -> float:
        return self.epoch + self.world.time

    async def sleep_until(self, t: float, idle) -> None:
        while (left := t - self.now()) > 1e-6:
            if self.fast_forward and idle():
                await self.world.sleep(min(left, self.STEP_S), drive=True)
            else:  # the task (or the listener) drives the world: look again soon
                await asyncio.sleep(0.2)


# -- the book: schedules on disk ---------------------------------------------------------------------
class ScheduleBook:
    """The schedules of one Core, in SQLite (`path`; None: in memory). Short calls, thread-safe."""

    def __init__(self, path: Path | None):
        self.path = path
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._db = open_migrated(path, MIGRATIONS, f"the Core's schedules {path or '(in memory)'}")

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def all(self) -> list[ScheduleRecord]:
        with self._lock:
            rows = self._db.execute("SELECT * FROM schedules ORDER BY due, id").fetchall()
        return [_record(r) for r in rows]

    def add(self, rec: ScheduleRecord) -> ScheduleRecord:
        with self._lock:
            cur = self._db.execute(
                "INSERT INTO schedules (robot_id, rapp, params, command, kind, time_of_day, due, window_s, created) "
                "VALUES (?,?,?,?,?,?,?,?,?)", (rec.robot_id, rec.rapp, json.dumps(rec.params), rec.command, rec.kind,
                                               rec.time_of_day, rec.due, rec.window_s, time.time()))
        return rec.model_copy(update={"id": cur.lastrowid})

    def remove(self, ids: list[int]) -> None:
        with self._lock:
            self._db.executemany("DELETE FROM schedules WHERE id=?", [(i,) for i in ids])

    def move(self, schedule_id: int, due: float) -> None:
        with self._lock:
            self._db.execute("UPDATE schedules SET due=? WHERE id=?", (due, schedule_id))


def _record(row: sqlite3.Row) -> ScheduleRecord:
    return ScheduleRecord(id=row["id"], robot_id=row["robot_id"], rapp=row["rapp"], params=json.loads(row["params"]),
                          command=row["command"], kind=row["kind"], time_of_day=row["time_of_day"], due=row["due"],
                          window_s=row["window_s"])


# -- times ---------------------------------------------------------------------------------------------
def local(t: float, tz: tzinfo) -> datetime:
    return datetime.fromtimestamp(t, tz)


def at_time(day: date, hour: int, minute: int, tz: tzinfo) -> float:
    return datetime(day.year, day.month, day.day, hour, minute, tzinfo=tz).timestamp()


def resolve(when: When, now: float, tz: tzinfo) -> tuple[str, float, str | None]:
    """(kind, first due, time of day) of a time as said; ScheduleRefused for one that cannot be kept."""
    today = local(now, tz).date()
    if when.kind == "in":
        return "once", now + (when.seconds or 0.0), None
    hour, minute = when.hour or 0, when.minute
    hhmm = f"{hour:02d}:{minute:02d}"
    if when.kind == "daily":
        due = at_time(today, hour, minute, tz)
        return "daily", due if due > now else at_time(today + timedelta(days=1), hour, minute, tz), hhmm
    if when.date:
        try:
            day = date.fromisoformat(when.date)
        except ValueError:
            raise ScheduleRefused(f"{when.date} is not a date") from None
        due = at_time(day, hour, minute, tz)
        if due <= now:
            raise ScheduleRefused(f"{when.date} at {hhmm} has passed (it is {_clock(now, tz, now)})")
    elif when.day == "today":
        due = at_time(today, hour, minute, tz)
        if due <= now:
            raise ScheduleRefused(f"{hhmm} today has passed (it is {_clock(now, tz, now)})")
    elif when.day == "tomorrow":
        due = at_time(today + timedelta(days=1), hour, minute, tz)
    else:  # the next such time
        due = at_time(today, hour, minute, tz)
        if due <= now:
            due = at_time(today + timedelta(days=1), hour, minute, tz)
    if due - now > MAX_AHEAD_S:
        raise ScheduleRefused(f"{when.date or hhmm} is more than a year ahead")
    return "once", due, None


def next_daily(rec: ScheduleRecord, after: float, tz: tzinfo) -> float:
    """The first start of a daily schedule after `after` (its local time of day, every day)."""
    hour, minute = (int(x) for x in (rec.time_of_day or "00:00").split(":"))
    day = local(after, tz).date()
    while (due := at_time(day, hour, minute, tz)) <= after:
        day += timedelta(days=1)
    return due


def _clock(t: float, tz: tzinfo, now: float) -> str:
    """'22:00', 'tomorrow at 07:00', 'on 2030-01-02 at 09:30' as the owner hears it."""
    when, today = local(t, tz), local(now, tz).date()
    hhmm = when.strftime("%H:%M")
    if when.date() == today:
        return hhmm if t >= now else f"{hhmm} today"
    if when.date() == today + timedelta(days=1):
        return f"tomorrow at {hhmm}"
    return f"on {when.date().isoformat()} at {hhmm}"


def describe(rec: ScheduleRecord, tz: tzinfo, now: float) -> str:
    if rec.kind == "daily":
        return f"{rec.rapp} every day at {rec.time_of_day} (#{rec.id}, next {_clock(rec.due, tz, now)})"
    return f"{rec.rapp} at {_clock(rec.due, tz, now)} (#{rec.id})"


def overlap(a: ScheduleRecord, b: ScheduleRecord) -> float | None:
    """The start of `b` (at or after b.due) whose span overlaps one of `a`'s; None if none does.
    Spans: [start, start + window_s); a daily schedule starts every DAY_S from its due."""
    def hits(t: float, w: float, other: ScheduleRecord) -> float | None:  # `other`'s start overlapping [t, t+w)
        if other.kind == "once":
            s = other.due
            return s if s < t + w and t < s + other.window_s else None
        k = max(0, math.floor((t - other.window_s - other.due) / DAY_S))
        for n in range(k, k + 3):
            s = other.due + n * DAY_S
            if s < t + w and t < s + other.window_s:
                return s
        return None

    if a.kind == "once":
        return hits(a.due, a.window_s, b)
    if b.kind == "once":
        return b.due if hits(b.due, b.window_s, a) is not None else None
    offset = (b.due - a.due) % DAY_S  # two daily ones: compare their times of day
    clash = offset < a.window_s or DAY_S - offset < b.window_s
    return b.due if clash else None


def fits(rec: ScheduleRecord, asked: ScheduleRequest, rapp: str, tz: tzinfo) -> bool:
    """Whether `rec` is one of the schedules a cancel names: its RApp, time of day, part of day."""
    if rapp and rec.rapp != rapp:
        return False
    when = local(rec.due, tz)
    if asked.when is not None and asked.when.hour is not None and \
            (when.hour, when.minute) != (asked.when.hour, asked.when.minute):
        return False
    if asked.part_of_day:
        lo, hi = PARTS[asked.part_of_day]
        hour = when.hour + (24 if when.hour < 5 and hi > 24 else 0)
        return lo <= hour < hi
    return True


# -- the scheduler ---------------------------------------------------------------------------------------
class Scheduler:
    """The Core's schedules: kept (`handle`), started at their time (the command queue), told to the
    owner. `core` is the CoreAgent: its catalogue, Store, running task, chat, records and queue."""

    def __init__(self, core, path: Path | None, clock: Clock | None = None):
        self.core = core
        self.clock = clock or WallClock()
        self.book = ScheduleBook(path)
        self._changed = asyncio.Event()
        self._task: asyncio.Task | None = None

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name=f"scheduler-{self.core.robot_id}")

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
        self.book.close()

    def schedules(self) -> list[ScheduleRecord]:
        return self.book.all()

    # -- the owner's words ------------------------------------------------------------------------
    async def handle(self, asked: ScheduleRequest, rapp: str, params: dict, command: str,
                     confirm: Confirm | None = None) -> None:
        """Keep, cancel or list schedules as the owner asked; the owner is told the outcome (chat,
        and a ScheduleChanged to the task subscribers), refusals with their reason. `confirm`: a new
        schedule is first checked, then kept only if the owner confirms it (a schedule heard by voice)."""
        try:
            if asked.action == ScheduleAction.ADD:
                rec = await self._keep(asked, rapp, params, command, confirm)
                await self._tell(ScheduleEvent.KEPT, f"I will run {describe(rec, self.clock.tz, self.clock.now())}.",
                                 [rec], command=command)
            elif asked.action == ScheduleAction.CANCEL:
                gone = await self._cancel(asked, rapp)
                now = self.clock.now()
                await self._tell(ScheduleEvent.CANCELLED, "Cancelled: " + "; ".join(
                    describe(r, self.clock.tz, now) for r in gone) + ".", gone, command=command)
            else:
                kept, now = self.book.all(), self.clock.now()
                text = ("Scheduled: " + "; ".join(describe(r, self.clock.tz, now) for r in kept) + "."
                        if kept else "Nothing is scheduled.")
                await self._tell(ScheduleEvent.LISTED, text, kept, command=command)
        except ScheduleRefused as e:
            await self._tell(ScheduleEvent.REFUSED, f"I cannot schedule that: {e}.", [], reason=str(e), command=command)
        except ScheduleDeclined as e:
            await self._tell(ScheduleEvent.REFUSED, e.told, [], reason=str(e), command=command)

    async def _keep(self, asked: ScheduleRequest, rapp: str, params: dict, command: str,
                    confirm: Confirm | None = None) -> ScheduleRecord:
        if confirm is not None:
            await self._check(asked, rapp, params, command)  # no question about what would be refused
            await confirm(command)
        return await self._check(asked, rapp, params, command, add=True)  # its time from now, after the answer

    async def _check(self, asked: ScheduleRequest, rapp: str, params: dict, command: str,
                     add: bool = False) -> ScheduleRecord:
        core, now = self.core, self.clock.now()
        if rapp not in {p.name for p in core.catalogue}:
            raise ScheduleRefused(f"the Store offers no application {rapp or '(none named)'} for a "
                                  f"{core.robot_type} robot")
        try:  # the most its task may take: what the robot is held for
            details = await core.request(core.store, S.Info(name=rapp), timeout=10.0)
            window = float(details.manifest.get("time_limit_s") or 600.0)
        except RequestError as e:
            raise ScheduleRefused(f"the Store did not tell {rapp}'s time limit ({e.reason})") from None
        kind, due, time_of_day = resolve(asked.when, now, self.clock.tz)
        rec = ScheduleRecord(id=0, robot_id=core.robot_id, rapp=rapp, params={k: str(v) for k, v in params.items()},
                             command=command, kind=kind, time_of_day=time_of_day, due=due, window_s=window)
        running = core.dynamic
        if running is not None and not running.ended.is_set():
            # its time limit runs on the machine's clock (the Core's s8 charges it, paused time left out);
            # the schedule's time is the robot's clock, a simulated one's far from the machine's: what is left
            left = running.manifest.time_limit_s - running.charged_s
            until = now + max(left, 0.0)
            if due < until:
                raise ScheduleRefused(f"the robot is busy with {running.rapp}, which may run until "
                                      f"{_clock(until, self.clock.tz, now)}")
        for other in self.book.all():
            at = overlap(other, rec)
            if at is not None:
                raise ScheduleRefused(f"it would clash with {describe(other, self.clock.tz, now)}, which may run "
                                      f"for {other.window_s / 60:.0f} min")
        if not add:
            return rec
        rec = await asyncio.to_thread(self.book.add, rec)
        self._changed.set()
        return rec

    async def _cancel(self, asked: ScheduleRequest, rapp: str) -> list[ScheduleRecord]:
        kept = self.book.all()
        fit = [r for r in kept if fits(r, asked, rapp, self.clock.tz)]
        if not fit:
            raise ScheduleRefused("no schedule fits that" + (f" (kept: {len(kept)}; ask \"what is scheduled?\")"
                                                             if kept else ": nothing is scheduled"))
        if len(fit) > 1 and not asked.every:
            now = self.clock.now()
            raise ScheduleRefused("which one? " + "; ".join(describe(r, self.clock.tz, now) for r in fit)
                                  + " (say \"cancel all ...\" for every one)")
        await asyncio.to_thread(self.book.remove, [r.id for r in fit])
        self._changed.set()
        return fit

    async def _tell(self, event: ScheduleEvent, text: str, schedules: list[ScheduleRecord], *, reason: str = "",
                    command: str = "") -> None:
        core = self.core
        core.record_structure(StructureEvent.SCHEDULE_KEPT if event == ScheduleEvent.KEPT
                              else StructureEvent.SCHEDULE_CANCELLED if event == ScheduleEvent.CANCELLED
                              else StructureEvent.SCHEDULE_LISTED if event == ScheduleEvent.LISTED
                              else StructureEvent.SCHEDULE_REFUSED if event == ScheduleEvent.REFUSED
                              else StructureEvent.SCHEDULE_MISSED,  # (literal names: tests/test_trace_records.py)
                              schedules=[r.id for r in schedules],
                              rapps=[r.rapp for r in schedules], reason=reason[:300], command=command[:200])
        await core.tell_user(text)
        await core.tell_watchers(ScheduleChanged(robot_id=core.robot_id, event=event, schedules=schedules,
                                                 reason=reason, command=command))

    # -- their times ------------------------------------------------------------------------------
    async def _run(self) -> None:
        try:
            await self._due_now(started=True)
            while True:
                kept = self.book.all()
                self._changed.clear()
                sleeper = asyncio.ensure_future(self.clock.sleep_until(kept[0].due, self._idle)) if kept else None
                changed = asyncio.ensure_future(self._changed.wait())
                try:
                    await asyncio.wait({t for t in (sleeper, changed) if t}, return_when=asyncio.FIRST_COMPLETED)
                finally:  # also when the Core stops meanwhile: no sleeper left to fail on a closed world
                    for t in (sleeper, changed):
                        if t is not None and not t.done():
                            t.cancel()
                if sleeper is not None and sleeper.done() and not sleeper.cancelled() and sleeper.exception():
                    raise sleeper.exception()
                await self._due_now()
        except asyncio.CancelledError:
            raise
        except Exception as e:  # noqa: BLE001 - a closed world (the run is ending): the schedules stay on disk
            log.warning("%s: scheduler stopped: %s", self.core.robot_id, e)

    def _idle(self) -> bool:
        return self.core.dynamic is None and self.core.commands.empty() and self.core.listening

    async def _due_now(self, started: bool = False) -> None:
        """Every schedule whose time has come: into the command queue (s3 takes it), or missed when
        it is more than LATE_S late (a Core that was stopped then)."""
        now = self.clock.now()
        for rec in self.book.all():
            if rec.due > now:
                continue
            if rec.kind == "daily":
                await asyncio.to_thread(self.book.move, rec.id, next_daily(rec, max(now, rec.due), self.clock.tz))
            else:
                await asyncio.to_thread(self.book.remove, [rec.id])
            if now - rec.due > LATE_S:
                await self.missed(rec, rec.due, "the robot's Core was not running then" if started
                                  else "it came due too late")
                continue
            self.core.record_structure("schedule-due", schedule=rec.id, rapp=rec.rapp, trigger="scheduled",
                                       due=_iso(rec.due, self.clock.tz), late_s=round(now - rec.due, 1))
            self.core.commands.put_nowait(ScheduledStart(rec, rec.due))

    def too_late(self, start: ScheduledStart) -> bool:
        """A due schedule taken from the queue only now (a commanded task held the robot meanwhile)."""
        return self.clock.now() - start.due > LATE_S

    async def missed(self, rec: ScheduleRecord, due: float, why: str) -> None:
        now = self.clock.now()
        reason = f"{rec.rapp} was due at {_clock(due, self.clock.tz, now)}: {why}"
        await self._tell(ScheduleEvent.MISSED, f"I missed a scheduled task: {reason}.", [rec], reason=reason,
                         command=rec.command)


def _iso(t: float, tz: tzinfo) -> str:
    return local(t, tz).isoformat(timespec="seconds")
