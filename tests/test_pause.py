"""The task's pause (behaviours/pause.py): FSMs hold before their next state, behaviours before their
next step, and a behaviour's timeout does not count paused time."""
import asyncio

from behaviours import FSM, Behaviour, Context, OneShot, PauseGate, Timeout, Wait


class Count(OneShot):
    def __init__(self, name, log):
        super().__init__(name)
        self.log = log

    async def action(self):
        self.log.append(self.name)


async def test_fsm_holds_its_next_state_while_paused():
    gate, log = PauseGate(), []
    fsm = FSM("f", initial="a")
    fsm.add_state("a", Count("a", log))
    fsm.add_state("b", Count("b", log), final=True)
    fsm.add_transition("a", "b")
    gate.pause("emergency stop")
    run = asyncio.create_task(fsm.run(Context(pause=gate)))
    await asyncio.sleep(0.2)
    assert log == [] and not run.done()
    gate.resume()
    assert (await run).ok and log == ["a", "b"]


async def test_a_timeout_does_not_count_paused_time():
    gate = PauseGate()

    class Slow(Behaviour):
        timeout = 0.6

        async def transition(self):
            await asyncio.sleep(0.1)

        def terminal(self):
            return self.iterations >= 5  # 0.5 s of work + 0.4 s paused: beyond 0.6 s only if paused time counted

    async def pause_a_while():
        await asyncio.sleep(0.05)
        gate.pause("stop")
        await asyncio.sleep(0.4)
        gate.resume()

    pauser = asyncio.create_task(pause_a_while())
    out = await Slow().run(Context(pause=gate))
    await pauser
    assert out.ok, out.reason
    assert 0.39 < gate.paused_seconds() < 0.6
    # without the pause the same timeout still ends it
    never = Wait(lambda memory: False, period=0.05, timeout=0.2)
    out = await never.run(Context(pause=PauseGate()))
    assert not out.ok and "timeout" in out.reason


async def test_the_timeout_decorator_does_not_count_paused_time_either():
    gate = PauseGate()
    slow = Timeout(Wait(lambda memory: memory.get("done", False), period=0.05), 0.3)
    ctx = Context(pause=gate)

    async def pause_then_finish():
        gate.pause("stop")
        await asyncio.sleep(0.5)  # longer than the timeout: only paused time
        gate.resume()
        await asyncio.sleep(0.1)
        ctx.memory["done"] = True

    helper = asyncio.create_task(pause_then_finish())
    out = await slow.run(ctx)
    await helper
    assert out.ok, out.reason
    out = await Timeout(Wait(lambda memory: False, period=0.05), 0.2).run(Context(pause=PauseGate()))
    assert not out.ok and "timeout after 0.2s" in out.reason


async def test_a_pause_stops_the_clock_only_up_to_its_allowance():
    """A task stopped for ever must still end (issue 42): paused time beyond the allowance counts."""
    from behaviours.pause import charged_seconds, run_pausable

    assert charged_seconds(10.0, 4.0, allowance_s=5.0) == 6.0
    assert charged_seconds(10.0, 8.0, allowance_s=5.0) == 5.0
    gate = PauseGate()
    gate.pause("stop")  # never resumed
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    try:
        await run_pausable(asyncio.sleep(30), 0.2, gate, allowance_s=0.3)
        raise AssertionError("a pause without end kept the timeout from expiring")
    except asyncio.TimeoutError:
        pass
    assert 0.45 <= loop.time() - t0 < 1.2  # 0.2 s limit + 0.3 s allowed pause


async def test_the_plan_monitor_counts_a_pause_beyond_its_allowance():
    """rapps/sdk/monitor.py: a leg held by an emergency stop that never ends fails its deadline."""
    from types import SimpleNamespace

    from agents.errors import RequestError
    from rapps.sdk.monitor import ArriveBy, PlanFailed, PlanMonitor

    async def no_events(*topics, handler=None):
        raise RequestError("no events here")

    traced = []
    task = SimpleNamespace(paused="stopped by the user", subscribe=no_events, _trace=lambda *a, **k: traced.append(k),
                           log=SimpleNamespace(warning=lambda *a: None))
    monitor = PlanMonitor(task, ArriveBy((1.0, 0.0), within_s=0.3), period_s=0.05, pause_allowance_s=0.4)
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    try:
        await monitor.run(asyncio.sleep(30))
        raise AssertionError("the held leg never failed")
    except PlanFailed as e:
        assert e.expectation == "arrive-by"
    assert 0.65 <= loop.time() - t0 < 1.5
    assert traced and traced[0]["expectation"] == "arrive-by"
