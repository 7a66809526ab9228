"""Render processes (robots/render_process.py): same pixels as the in-process renderer, no event-loop
stall, restart after a crash, no leftover processes."""
import asyncio
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from robots import World
from robots.errors import InvalidArgument

from .conftest import api_at

ROOT = Path(__file__).resolve().parents[2]


def _gone(pid: int) -> bool:
    """True when the process no longer runs (absent, or a zombie that is not our child)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def _both(world, cam, w=320, h=240):
    inline = world.run_sync(cam.capture, w, h).astype(int)
    process = world.capture_sync(cam, w, h).astype(int)
    return inline, process


def test_process_render_matches_inline_render(make_world):
    world = make_world("small", seed=1, overrides={"doors": {"d1": 0}, "lamps": {"l1": True}})
    assert world.render_mode == "process"
    nao = world.add_robot("nao", pose=(0.5, 0.0, math.pi / 2))
    ek = world.add_robot("elektron", pose=(0.5, 2.0, -math.pi / 2))  # facing each other
    cams = [nao.cameras["top"], ek.cameras["head"]]
    for cam in cams:
        a, b = _both(world, cam)
        assert np.abs(a - b).mean() < 0.5, cam.name
        # the other robot is in view and rendered by the mirror too
        assert a.std() > 5
    # dynamic state changes reach the render process (only differences are sent)
    world.run_sync(world.set_door_in_thread, "d1", 60)
    world.run_sync(world._set_lamp, "l1", False)
    world.run_sync(nao.set_base_pose, 0.6, 0.2, math.pi / 2 + 0.3)
    world.run_sync(nao.set_joint, "HeadYaw", -0.4)
    world.run_sync(ek.set_joint, "HeadTilt", 0.3)
    world.run_sync(ek.set_base_pose, 0.4, 1.8, -math.pi / 2 - 0.2)
    nao.cameras["top"].set_params(exposure=1.5, contrast=1.2)
    for cam in cams:
        a, b = _both(world, cam)
        assert np.abs(a - b).mean() < 0.5, cam.name
    # robots added after the render process started are mirrored as well
    world.add_robot("nao", name="nao2", pose=(0.5, 1.0, -math.pi / 2))
    a, b = _both(world, cams[0])
    assert np.abs(a - b).mean() < 0.5


async def test_api_capture_renders_in_process_and_inline_option(make_world):
    worlds = [make_world("small", seed=1, overrides={"lamps": {"l1": True}}, render=mode)
              for mode in ("process", "inline")]
    imgs = []
    for w in worlds:
        api = api_at(w, "nao", (0.5, 0.0, 90))
        imgs.append((await api.capture_array()).astype(int))
    assert worlds[0].render_pids() and not worlds[1].render_pids()
    assert np.abs(imgs[0] - imgs[1]).mean() < 0.5
    with pytest.raises(InvalidArgument):
        World.from_file("small", render="gpu")


def test_a_large_frame_renders_in_bands_on_both_processes_and_alike_when_one_is_busy(make_world):
    world = make_world("small", seed=1, overrides={"doors": {"d1": 0}, "lamps": {"l1": True}}, render_bands=2)
    cam = world.add_robot("nao", pose=(0.5, 0.0, math.pi / 2)).cameras["top"]
    inline = world.run_sync(cam.capture, 1280, 960).astype(int)
    banded = world.capture_sync(cam, 1280, 960)
    assert len(world.render_pids()) == 2  # one band each, at once
    # the same picture; a band's projection moves TinyRenderer's rounding: a few coplanar (z-fighting) pixels differ
    assert (inline != banded).any(2).mean() < 0.003
    pool = world._renderer
    held = pool._acquire()  # one process busy: the other renders both bands
    try:
        alone = world.capture_sync(cam, 1280, 960)
    finally:
        pool._release(held)
    assert np.array_equal(alone, banded)


async def test_event_loop_keeps_ticking_while_a_large_frame_renders(make_world):
    world = make_world("small", seed=1)
    api = api_at(world, "nao", (0.5, 0.0, 90))
    await api.capture_array(resolution="160x120")  # render process started
    loop = asyncio.get_running_loop()
    late = []

    async def ticker():
        while True:
            t = loop.time()
            await asyncio.sleep(0.01)
            late.append(loop.time() - t - 0.01)

    task = asyncio.create_task(ticker())
    t0 = time.perf_counter()
    img = await api.capture_array(resolution="1280x960")
    took = time.perf_counter() - t0
    task.cancel()
    assert img.shape == (960, 1280, 3)
    assert len(late) >= 3
    assert max(late) < 0.15, (max(late), took)


async def test_render_process_restarts_after_a_crash_and_close_reaps_it(make_world):
    world = make_world("small", seed=1)
    api = api_at(world, "nao", (0.5, 0.0, 90))
    first = await api.capture_array()
    (pid,) = world.render_pids()
    os.kill(pid, 9)
    again = await api.capture_array()
    assert np.array_equal(first, again)
    (pid2,) = world.render_pids()
    assert pid2 != pid and _gone(pid)
    # concurrent captures use a second process
    await asyncio.gather(*(api.capture_array() for _ in range(4)))
    pids = world.render_pids()
    assert 1 <= len(pids) <= 2
    world.close()
    assert not world.render_pids()
    assert all(_gone(p) for p in pids + [pid2])


@pytest.mark.parametrize("own_session", [False, True])
def test_render_processes_exit_with_their_parent(tmp_path, own_session):
    script = textwrap.dedent(f"""
        import os, sys
        from robots import World
        w = World.from_file("small", seed=1)
        r = w.add_robot("nao", pose=(0.5, 0.0, 1.57))
        w.start_renderer(own_session={own_session})
        w.capture_sync(r.cameras["top"], 64, 48)
        print(*[f"{{p}}:{{os.getsid(p)}}" for p in w.render_pids()], flush=True)
        os._exit(0)   # no close(), no atexit: the render processes see EOF and exit
    """)
    out = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120)
    found = [tuple(int(n) for n in x.split(":")) for x in out.stdout.split()]
    pids = [p for p, _ in found]
    assert pids, out.stderr
    # in a session of its own, a process's scheduling group can be set apart (bench/fleet.py)
    assert all((sid == p) == own_session for p, sid in found)
    deadline = time.time() + 10
    while not all(_gone(p) for p in pids) and time.time() < deadline:
        time.sleep(0.1)
    assert all(_gone(p) for p in pids)


async def test_render_error_reaches_the_caller_and_the_next_frame_renders(make_world):
    from dataclasses import replace

    from robots.errors import RobotError
    world = make_world("small", seed=1)
    api = api_at(world, "nao", (0.5, 0.0, 90))
    api.robot.set_failure_modes(None)  # a fixed exposure: auto-exposure would not read the bad one
    good = await api.capture_array()
    cam = api.robot.cameras["top"]
    cam.params, saved = replace(cam.params, exposure="bad"), cam.params  # fails in the render process
    with pytest.raises(RobotError, match="render"):
        await api.capture_array()
    cam.params = saved
    assert np.array_equal(await api.capture_array(), good)


def test_render_processes_exit_with_their_parent_though_a_fork_holds_the_pipe(tmp_path):
    # a process the parent forked without exec keeps the render pipe's write end: no EOF comes
    script = textwrap.dedent("""
        import os, sys, time
        from robots import World
        w = World.from_file("small", seed=1)
        r = w.add_robot("nao", pose=(0.5, 0.0, 1.57))
        w.capture_sync(r.cameras["top"], 64, 48)
        child = os.fork()
        if child == 0:
            time.sleep(30)
            os._exit(0)
        print(f"fork:{child}", *w.render_pids(), flush=True)
        os._exit(0)
    """)
    out = tmp_path / "out.txt"  # a file, not a pipe the fork would keep open: run() returns at the exit
    with out.open("w") as f:
        subprocess.run([sys.executable, "-c", script], cwd=ROOT, stdout=f, stderr=subprocess.STDOUT, timeout=120)
    words = out.read_text().split()
    fork = next(int(x[5:]) for x in words if x.startswith("fork:"))
    pids = [int(x) for x in words if x.isdigit()]
    try:
        assert pids, words
        deadline = time.time() + 5
        while not all(_gone(p) for p in pids) and time.time() < deadline:
            time.sleep(0.1)
        assert all(_gone(p) for p in pids)
    finally:
        os.kill(fork, signal.SIGKILL)
