"""Scheduled tasks (paper 000 sec. 7's trigger, agents/scheduler.py): the owner writes a time, the
Core keeps the schedule in its data directory and starts the RApp through fig. 5 when the robot's
simulated clock comes to it, with trigger "scheduled" in the trace and the task record; a restart
of the Core keeps it, "cancel" removes it, and one it cannot keep is refused with its reason."""
from __future__ import annotations

from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
import yaml

from agents.core_agent import CoreAgent, CoreOptions
from agents.scheduler import LATE_S, ScheduleBook, ScheduledStart, ScheduleRefused, Scheduler, WorldClock, overlap, resolve
from agents.services.context import ServiceContext
from agents.services.errors import ServiceError
from agents.services.interpretation import interpret_command, parse_schedule
from agents.tracing import read_trace
from ontology.results import ScheduleEvent, ScheduleRecord, TaskTrigger
from ontology.services.interpretation import InterpretCommand, RAppDescription, ScheduleAction, When
from robots import RobotAPI, World
from scenarios.system import RappSystem, wait_until

from .test_lifecycle import variant as lifecycle_variant

FIXTURE = Path(__file__).parent / "fixtures" / "echo_app"
TZ = timezone(timedelta(hours=1))
EVENING = datetime(2030, 3, 4, 21, 58, tzinfo=TZ)  # the robot's clock when the world starts


# -- the words (the Platform's interpretation) -----------------------------------------------------
HAZARD = [RAppDescription(name="hazard-detection", keywords=["hazards"], phrases=["check the hazards"])]


@pytest.mark.parametrize("text, kind, hour, seconds, day", [
    ("check the hazards every day at 22:00", "daily", 22, None, None),
    ("Check the hazards in ten minutes", "in", None, 600, None),
    ("check the hazards in twenty-five minutes", "in", None, 1500, None),
    ("check the hazards tomorrow at 7 am", "at", 7, None, "tomorrow"),
    ("check the hazards tonight at ten", "at", 22, None, "today"),
    ("check the hazards at 9:30 pm", "at", 21, None, None),
])
def test_a_time_in_a_command_is_a_schedule_and_the_rest_names_the_rapp(text, kind, hour, seconds, day):
    out = interpret_command(InterpretCommand(text=text, robot_type="nao", rapps=HAZARD), ServiceContext(user="u", state=None))
    assert out.rapp == "hazard-detection" and out.schedule.action == ScheduleAction.ADD
    when = out.schedule.when
    assert (when.kind, when.hour, when.seconds, when.day) == (kind, hour, seconds, day)


def test_cancel_and_list_need_no_rapp_and_a_bad_time_is_refused():
    ctx = ServiceContext(user="u", state=None)
    cancel = interpret_command(InterpretCommand(text="cancel the evening check", rapps=HAZARD), ctx)
    assert (cancel.rapp, cancel.schedule.action, cancel.schedule.part_of_day) == ("", "cancel", "evening")
    assert parse_schedule("what is scheduled?")[0].action == ScheduleAction.LIST
    assert parse_schedule("cancel all the hazard checks")[0].every
    assert parse_schedule("what's the weather in Warsaw")[0] is None  # no time: no schedule
    with pytest.raises(ServiceError, match="25:00 is not a time of day"):
        parse_schedule("check the hazards at 25:00")
    with pytest.raises(ServiceError, match="at what time"):
        parse_schedule("check the hazards every day")


# -- times and clashes (the Core) -------------------------------------------------------------------
def test_times_resolve_against_the_robots_clock_and_past_ones_are_refused():
    now = EVENING.timestamp()
    assert resolve(When(kind="daily", hour=22), now, TZ) == ("daily", now + 120, "22:00")
    assert resolve(When(kind="daily", hour=21, minute=30), now, TZ)[1] == now + 120 + 23.5 * 3600  # tomorrow's
    assert resolve(When(kind="at", hour=7), now, TZ)[1] == now + 120 + 9 * 3600  # the next 7:00
    with pytest.raises(ScheduleRefused, match="07:00 today has passed"):
        resolve(When(kind="at", hour=7, day="today"), now, TZ)
    with pytest.raises(ScheduleRefused, match="has passed"):
        resolve(When(kind="at", hour=7, date="2030-03-01"), now, TZ)
    with pytest.raises(ScheduleRefused, match="more than a year ahead"):
        resolve(When(kind="at", hour=7, date="2032-01-01"), now, TZ)


def rec(kind: str, due: float, window: float = 3600.0, sid: int = 1) -> ScheduleRecord:
    return ScheduleRecord(id=sid, robot_id="nao1", rapp="x", kind=kind, due=due, window_s=window,
                          time_of_day="22:00" if kind == "daily" else None)


def test_schedules_clash_when_their_tasks_could_overlap():
    t = EVENING.timestamp()
    daily = rec("daily", t)
    assert overlap(daily, rec("daily", t + 1800)) is not None  # 22:30 daily: the 22:00 check may still run
    assert overlap(daily, rec("daily", t + 3 * 3600)) is None
    assert overlap(daily, rec("daily", t - 1800, window=3600)) is not None  # its own hour reaches 22:00
    assert overlap(daily, rec("once", t + 5 * 86400 + 600, 60)) is not None  # a day later, 22:10
    assert overlap(daily, rec("once", t + 5 * 86400 + 4000, 60)) is None
    assert overlap(rec("once", t, 60), rec("once", t + 30, 60)) is not None
    assert overlap(rec("once", t, 60), rec("once", t + 61, 60)) is None


class RacingClock:
    """The robot's clock of a simulation running far ahead of the machine: it moves only when told."""

    tz = TZ

    def __init__(self):
        self.t = EVENING.timestamp()

    def now(self) -> float:
        return self.t


def test_how_late_a_schedule_may_start_is_counted_on_the_robots_clock():
    # a schedule come due while a commanded task held the robot: LATE_S of the robot's clock, however
    # few of the machine's seconds went by meanwhile (here none)
    clock = RacingClock()
    scheduler = Scheduler(core=None, path=None, clock=clock)
    start = ScheduledStart(rec("once", clock.now()), clock.now())
    clock.t += LATE_S - 1
    assert not scheduler.too_late(start)
    clock.t += 2
    assert scheduler.too_late(start)
    scheduler.book.close()


def test_the_book_keeps_its_schedules_on_disk(tmp_path):
    path = tmp_path / "core" / "schedules.db"
    book = ScheduleBook(path)
    kept = book.add(rec("daily", 1e9))
    book.close()
    again = ScheduleBook(path)
    assert [r.id for r in again.all()] == [kept.id] and again.all()[0].kind == "daily"
    assert again._db.execute("PRAGMA user_version").fetchone()[0] == 1
    assert oct(path.stat().st_mode & 0o777) == "0o600"
    again.close()


# -- on a real system, the robot's clock simulated ----------------------------------------------------
def variant(tmp_path: Path, name: str, keyword: str, phrases: list[str], **params) -> Path:
    """The echo RApp under another name, keyword and phrases, with other default params."""
    src = lifecycle_variant(tmp_path, name, keyword, **params)
    manifest = yaml.safe_load((src / "manifest.yaml").read_text())
    (src / "manifest.yaml").write_text(yaml.safe_dump({**manifest, "phrases": phrases}))
    return src


async def start_core(system, handle_kw: dict) -> CoreAgent:
    core = CoreAgent(**handle_kw)
    await core.start()
    return core


async def test_a_schedule_starts_its_rapp_kept_across_a_restart_refused_and_cancelled(tmp_path):
    world = World.from_file("small", seed=2)
    try:
        async with RappSystem(tmp_path / "run", trace_file=tmp_path / "trace.jsonl") as system:
            await system.publish(FIXTURE)
            await system.publish(variant(tmp_path, "linger-app", "linger", phrases=[], behaviour="linger", seconds=10))
            clock = WorldClock(world, EVENING, fast_forward=True)
            handle = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")), data_dir=tmp_path / "core",
                                            clock=clock, hear_audio=False)
            core, user = handle.core, handle.user
            await user.watch_tasks(core.address)
            await wait_until(lambda: core.vocabulary and core.listening)

            async def tell(text: str):
                start = len(user.schedules)
                await user.say(core.address, text)
                return await user.schedule_change(30, start)

            # in ten minutes of the robot's clock: kept, then started by the schedule, not by a command
            kept = await tell("please echo something back in ten minutes")
            assert kept.event == ScheduleEvent.KEPT and kept.schedules[0].due == pytest.approx(EVENING.timestamp() + 600, abs=2)
            record = await user.task_end(120)
            assert record.ok and record.trigger == TaskTrigger.SCHEDULED and record.schedule_id == kept.schedules[0].id
            assert record.rapp == "echo-app" and clock.now() >= EVENING.timestamp() + 600
            trace = read_trace(tmp_path / "trace.jsonl", validate=True)
            due = next(r for r in trace if r.get("event") == "schedule-due")
            handoff = next(r for r in trace if r.get("event") == "handoff")
            assert due["trigger"] == "scheduled" and handoff["trigger"] == "scheduled" and due["t"] < handoff["t"]
            states = [r["state"] for r in trace if r["kind"] == "state" and r.get("fsm") == "core" and r["t"] > due["t"]]
            assert states[:5] == ["s4a_keyword", "s5_download", "s6_activate", "s8_serve", "s10_destroy"], states
            assert not core.scheduler.schedules()  # a once schedule is forgotten when it starts

            # refused with their reasons: a time gone, a clash with a kept one, a RApp the Store lacks
            refused = await tell("please echo something back today at 7:00")
            assert refused.event == ScheduleEvent.REFUSED and "07:00 today has passed" in refused.reason
            daily = await tell("please echo something back every day at 23:00")
            assert daily.event == ScheduleEvent.KEPT and daily.schedules[0].kind == "daily"
            clash = await tell("please echo something back tonight at 23:00")
            assert clash.event == ScheduleEvent.REFUSED and "clash" in clash.reason
            assert "I cannot schedule that" in user.texts()[-1]

            # a restart of the Core (its data directory kept) keeps the daily one; its clock reads 23:15
            # now (the robot was off meanwhile): tonight's 23:00 is missed, told, and moved to tomorrow
            later = WorldClock(world, datetime.fromtimestamp(clock.now(), TZ) + timedelta(hours=1, minutes=15))
            kw = dict(name=f"core-{core.robot_id}", robot_id=core.robot_id, robot_type=core.robot_type, robot_api=core.robot,
                      owner=f"owner-{core.robot_id}", platform="platform", store="store", user=core.user, password=core.password,
                      settings=system.settings,
                      options=CoreOptions(workdir=tmp_path / "core-work-2", trusted_keys=[system.public_key],
                                          require_signature=True, data_dir=tmp_path / "core", clock=later,
                                          hear_audio=False))
            await core.stop()
            core = await start_core(system, kw)
            try:
                await user.watch_tasks(core.address)
                await wait_until(lambda: core.vocabulary and core.listening)
                assert [(s.kind, s.time_of_day) for s in core.scheduler.schedules()] == [("daily", "23:00")]
                missed = await user.wait_for(lambda t: t.startswith("I missed"), timeout=30)
                assert "echo-app was due at 23:00 today: the robot's Core was not running then" in missed, missed
                assert core.scheduler.schedules()[0].due == pytest.approx(daily.schedules[0].due + 86400)
                assert any(r.get("event") == "schedule-missed" for r in read_trace(tmp_path / "trace.jsonl"))
                listed = await tell("what is scheduled?")
                assert listed.event == ScheduleEvent.LISTED and "every day at 23:00" in user.texts()[-1]
                gone = await tell("cancel the evening check")
                assert gone.event == ScheduleEvent.CANCELLED and gone.schedules[0].id == daily.schedules[0].id
                assert not core.scheduler.schedules()
                none = await tell("cancel the evening check")
                assert none.event == ScheduleEvent.REFUSED and "nothing is scheduled" in none.reason

                # the robot busy: a task running now may hold it until its start + its time limit (60 s)
                ended = len(user.ended)
                await user.say(core.address, "linger")
                await wait_until(lambda: core.dynamic is not None and core.dynamic.started is not None, 60)  # s8
                busy = await tell("please echo something back in ten seconds")  # by chat, during the task
                assert busy.event == ScheduleEvent.REFUSED and "the robot is busy with linger-app" in busy.reason
                assert (await user.task_end(60, ended)).rapp == "linger-app"
            finally:
                await core.stop()
    finally:
        world.close()
