"""Live progress of a run: the rich panel (scenarios.progress) and the --watch page (scenarios.watch)
served from a real simulated robot driving a planned path and capturing a real camera frame, read in
headless Chromium.

The browser test needs the Debian package `chromium` (/usr/bin/chromium) and the pip package
`playwright` (the system Chromium is used); it is skipped without them.
"""
from __future__ import annotations

import asyncio
import io
import json
import shutil
import time
import urllib.request
from pathlib import Path

import pytest
from rich.console import Console

from agents.tracing import TraceWriter
from ontology.robot import CaptureImage, MoveAlongPath, Pose2D
from robots import RobotAPI, World
from scenarios.home_setup import home_map
from scenarios.progress import RunView, follow, render
from scenarios.recorder import RecordingAPI
from scenarios.watch import WatchServer, WatchState

from .test_progress import chat

CORE, DYN, OWNER = "core-nao1@localhost", "dyn-nao1-hazard-1@localhost", "owner-nao1@localhost"


def write_run(writer: TraceWriter, chats: int = 7) -> None:
    """A run's records as the agents write them: Core and RApp states, a spawn, chat lines, and the
    RApp's progress record."""
    writer.record("state", event="enter", agent=CORE, fsm="core", state="s8_serve")
    writer.record("structure", event="spawn", agent=CORE, dynamic=DYN)
    writer.record("state", event="enter", agent=DYN, fsm="hazard", state="check_door")
    writer.record("progress", agent=DYN, fraction=0.4, text="door d1 checked")
    writer.record("progress", agent=DYN, fraction=7, text="not a fraction: ignored")
    for i in range(chats):
        writer.record("message", dir="send", **chat(CORE, OWNER, f"line {i}"))


def panel_text(view: RunView, width: int = 100) -> str:
    console = Console(record=True, file=io.StringIO(), width=width)
    console.print(render(view, title="rapp run hazard"))
    return console.export_text()


async def test_live_panel_shows_states_pose_progress_and_last_chat_lines(tmp_path):
    path = tmp_path / "trace.jsonl"
    writer = TraceWriter(path)
    out, view = io.StringIO(), RunView()
    follower = asyncio.create_task(follow(path, pose=lambda: (1.25, 2.5, 1.5708), out=out, period=0.05,
                                          live=True, view=view, title="rapp run hazard"))
    write_run(writer)
    await asyncio.sleep(0.3)
    assert (view.core, view.rapp, view.rapp_state) == ("s8_serve", "hazard", "check_door")
    text = panel_text(view)
    for shown in ("Core     s8_serve", "RApp     hazard: check_door", "x 1.25  y 2.50  θ 90°",
                  "40% door d1 checked", "core-nao1: spawn dyn-nao1-hazard-1", "rapp run hazard · "):
        assert shown in text, (shown, text)
    assert "core-nao1 -> owner-nao1: line 6" in text and "line 2" in text
    assert "line 1" not in text and "not a fraction" not in text  # the last 5 chat lines only
    writer.record("state", event="enter", agent=CORE, fsm="core", state="s3_listen")
    follower.cancel()
    await follower
    final = out.getvalue()  # a file gets the last panel once, when the display stops
    assert "s3_listen" in final and "hazard: check_door" in final and "\x1b[" not in final
    writer.close()


async def test_plain_lines_include_the_progress_record(tmp_path):
    path, out = tmp_path / "trace.jsonl", io.StringIO()
    writer = TraceWriter(path)
    follower = asyncio.create_task(follow(path, out=out, period=0.05))  # a StringIO is no terminal
    write_run(writer, chats=1)
    await asyncio.sleep(0.2)
    follower.cancel()
    await follower
    text = out.getvalue()
    assert "progress dyn-nao1-hazard-1: 40% door d1 checked" in text and "╭" not in text
    assert "rapp hazard: check_door" in text and "chat core-nao1 -> owner-nao1: line 0" in text
    writer.close()


# -- the --watch page in a real headless browser ------------------------------------------------
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
ORANGE = "d => { const c = d.getContext('2d').getImageData(0, 0, d.width, d.height).data; let n = 0;" \
         " for (let i = 0; i < c.length; i += 4) if (c[i] > 200 && c[i+1] > 100 && c[i+1] < 150 && c[i+2] < 40) n++;" \
         " return n; }"


@pytest.fixture
async def browser():
    async_api = pytest.importorskip("playwright.async_api", reason="pip package 'playwright' is not installed")
    exe = CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium")
    if not exe:
        pytest.skip("Debian package 'chromium' is not installed (no /usr/bin/chromium)")
    # SPADE sets uvloop's policy globally once imported (docs/spade-pitfalls.md): this standard
    # loop's subprocesses (playwright's driver) then need the standard policy's child watcher back
    policy = asyncio.get_event_loop_policy()
    asyncio.set_event_loop_policy(asyncio.DefaultEventLoopPolicy())
    try:
        async with async_api.async_playwright() as pw:
            try:
                browser = await pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS, timeout=15000)
            except Exception as e:  # noqa: BLE001 - a broken browser install is an environment issue
                pytest.skip(f"chromium at {exe} does not start under playwright: {e}")
            try:
                yield browser
            finally:
                await browser.close()
    finally:
        asyncio.set_event_loop_policy(policy)


@pytest.fixture
def world():
    w = World.from_file("small", seed=1, rtf=3.0)  # 3x real time: the move spans several page polls
    yield w
    w.close()


async def robot_px(page) -> tuple[int, int]:
    value = await page.get_attribute("#map", "data-robot")
    return tuple(map(int, value.split(",")))


async def test_watch_page_shows_robot_moving_path_and_camera_frame(browser, world):
    started = time.monotonic()
    recorder = RecordingAPI(RobotAPI(world.add_robot("elektron")))
    view = RunView()
    view.apply({"kind": "state", "event": "enter", "agent": CORE, "fsm": "core", "state": "s8_serve"})
    view.apply({"kind": "message", "dir": "send", "performative": "chat", "agent": CORE, "receiver": OWNER,
                "content": '<img src=x onerror="window.__pwned=1">'})  # shown as text, never markup
    server = WatchServer(WatchState(home_map(world, "small"), pose=lambda: recorder.robot.pose,
                                    recorder=recorder, view=view, title="watch test"), port=0)
    url = await server.start()
    assert url.startswith("http://127.0.0.1:")
    mover = None
    try:
        page = await browser.new_page(viewport={"width": 1300, "height": 900})
        page.set_default_timeout(8000)
        problems, remote = [], []
        page.on("console", lambda m: m.type == "error" and problems.append(m.text))
        page.on("pageerror", lambda e: problems.append(str(e)))

        async def only_local(route):  # offline: a CDN or any other host would show here
            if route.request.url.startswith(url):
                await route.continue_()
            else:
                remote.append(route.request.url)
                await route.abort()
        await page.route("**/*", only_local)
        await page.goto(url)
        await page.wait_for_function("document.querySelector('#map').dataset.robot !== ''")
        assert await page.text_content("#core") == "s8_serve"
        assert "onerror" in await page.text_content("#chat li")
        assert await page.evaluate("window.__pwned") is None
        x0, y0 = recorder.robot.pose[:2]
        start_px = await robot_px(page)

        # drive 1.6 m north along a planned path: the robot moves on the canvas, the leg is drawn
        path = [Pose2D(x=x0, y=y0 + d, theta=1.5708) for d in (0.0, 0.8, 1.6)]
        mover = asyncio.create_task(recorder.handle(MoveAlongPath(poses=path)))
        await page.wait_for_function(f"document.querySelector('#map').dataset.robot !== '{start_px[0]},{start_px[1]}'")
        moving_px = await robot_px(page)
        assert moving_px[1] < start_px[1] and abs(moving_px[0] - start_px[0]) <= 3  # north = up the canvas
        assert await page.locator("#map").evaluate(ORANGE) > 20  # the leg being driven
        await asyncio.sleep(0.7)
        later_px = await robot_px(page)
        assert later_px[1] < moving_px[1]  # still moving: the page follows the run
        await mover
        await page.wait_for_function("document.querySelector('#pose').textContent.includes('y 2.')")
        assert recorder.robot.pose[1] > y0 + 1.4

        # a real camera frame: the page loads it when the capture count changes
        assert await page.get_attribute("#frame", "data-n") == "0"
        await recorder.handle(CaptureImage(resolution="320x240"))
        await page.wait_for_function("document.querySelector('#frame').dataset.n === '1'")
        assert await page.evaluate("document.querySelector('#frame').naturalWidth") == 320
        view.apply({"kind": "progress", "agent": DYN, "fraction": 0.5, "text": "half way"})
        await page.wait_for_function("document.querySelector('#progress').dataset.fraction === '0.5'")
        assert await page.text_content("#progress-text") == "50% half way"
        state = await fetch_json(url + "state.json?legs=1")  # the page knows the one leg: not resent
        assert state["legs_total"] == 1 and "legs" not in state and state["current_leg"] is None
        trail = state["trail"]  # the driven trail, sampled while the page polled and between polls
        assert state["captures"] == 1 and len(trail) >= 8
        assert abs(trail[0][1] - y0) < 0.05 and trail[-1][1] > y0 + 1.4
        assert problems == [] and remote == []
    finally:
        if mover is not None:
            mover.cancel()
            await asyncio.gather(mover, return_exceptions=True)
        await server.stop()
    assert time.monotonic() - started < 20


async def fetch_json(url: str) -> dict:
    return json.loads(await asyncio.to_thread(lambda: urllib.request.urlopen(url, timeout=5).read()))
