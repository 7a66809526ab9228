"""Per-robot builds in the Store (paper 000 sec. 6.2; agents/store_build.py): a publish runs the
package's own tests in the sandbox once per robot type its manifest declares, lists it for the types
that passed, keeps each build's log and says why a type was refused; `rapp store serve`'s page shows
packages, versions, builds and logs (in headless Chromium, as the trace viewer is tested)."""
from __future__ import annotations

import asyncio
import sqlite3
import textwrap
from pathlib import Path

import pytest
import yaml

from agents.store_repository import MIGRATIONS, StoreRepository, _SCHEMA
from ontology import store as S
from ontology.package import build_package_bytes
from scenarios.store_page import StorePage
from scenarios.system import RappSystem

from .test_watch import browser  # noqa: F401 - the headless Chromium fixture

FIXTURE = Path(__file__).parent / "fixtures" / "echo_app"


def tiny_rapp(where: Path, name: str = "tiny-speaker", tests: bool = True) -> Path:
    """A RApp whose own test needs speech: it passes for a NAO and fails for an Elektron (no speaker)."""
    src = where / name
    (src / "tiny_speaker").mkdir(parents=True)
    (src / "tiny_speaker" / "__init__.py").write_text("")
    (src / "tiny_speaker" / "task.py").write_text(textwrap.dedent('''\
        from rapps.sdk import FSM, Step, Task


        class SpeakTask(Task):
            def build(self):
                fsm = FSM("speak", initial="say")
                fsm.add_state("say", Step(self.speak), final=True)
                return fsm

            async def speak(self, memory):
                await self.say("hello")
        '''))
    (src / "manifest.yaml").write_text(yaml.safe_dump({
        "name": name, "version": "1.0.0", "description": "Says hello.", "robot_types": ["nao", "elektron"],
        "keywords": ["hello"], "entry_point": "tiny_speaker.task:SpeakTask", "robot_api": ["communication"],
        "time_limit_s": 30}))
    if tests:
        (src / "tests").mkdir()
        (src / "tests" / "test_speaker.py").write_text(textwrap.dedent('''\
            import os


            def test_the_robot_can_speak():
                robot = os.environ["RAPP_ROBOT_TYPE"]
                assert robot != "elektron", f"a{'n' if robot[0] in 'aeiou' else ''} {robot} has no speech synthesizer"


            def test_the_build_runs_in_the_sandbox():  # its own root: the run's directory, no /proc, no network
                assert os.getcwd() == "/app" and not os.path.exists("/proc/self") and os.environ["HOME"] == "/app/tmp"
            '''))
    return src


async def builds_done(system, name: str, timeout_s: float = 150.0) -> list[S.BuildInfo]:
    """The package's builds once none is queued or running."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while True:
        reply = await system.publisher.request(system.store_address, S.Builds(name=name))
        if reply.builds and all(b.state not in ("queued", "building") for b in reply.builds):
            return reply.builds
        if loop.time() > deadline:
            raise TimeoutError(f"builds of {name} not done within {timeout_s:g} s: {reply.builds}")
        await asyncio.sleep(0.5)


async def test_a_publish_builds_per_robot_type_lists_the_passed_and_tells_why_not(tmp_path, browser):  # noqa: F811
    async with RappSystem(tmp_path / "run", trace_file=tmp_path / "trace.jsonl", store_kw={"build": True}) as system:
        details_text = await system.publish(tiny_rapp(tmp_path))
        assert details_text == "tiny-speaker 1.0.0"
        builds = {b.robot_type: b for b in await builds_done(system, "tiny-speaker")}
        assert builds["nao"].state == "passed" and builds["elektron"].state == "failed", builds
        assert "an elektron has no speech synthesizer" in builds["elektron"].reason
        assert builds["elektron"].started <= builds["elektron"].ended
        ask = system.publisher.request
        nao = await ask(system.store_address, S.ListPackages(robot_type="nao"))
        elektron = await ask(system.store_address, S.ListPackages(robot_type="elektron"))
        assert [p.name for p in nao.packages] == ["tiny-speaker"] and nao.packages[0].robot_types == ["nao"]
        assert elektron.packages == []
        log = await ask(system.store_address, S.BuildLog(name="tiny-speaker", version="1.0.0", robot_type="elektron"))
        assert "1 failed, 1 passed" in log.log and "no speech synthesizer" in log.log
        # a package without tests is compiled only and listed at once ("untested"); the echo RApp's
        await system.publish(FIXTURE)
        echo = await ask(system.store_address, S.Info(name="echo-app"))
        assert {b.state for b in echo.builds} == {"untested"} and echo.summary.robot_types == ["nao", "elektron"]

        # the developers' page: packages, versions, builds; a failed build's log
        page_server = StorePage(system.publisher, system.store_address, port=0)
        url = await page_server.start()
        try:
            page = await browser.new_page()
            page.set_default_timeout(10000)
            problems = []
            page.on("pageerror", lambda e: problems.append(str(e)))
            await page.goto(url)
            row = page.locator('section[data-package="tiny-speaker"] tr[data-robot-type="elektron"]')
            await row.wait_for()
            assert await row.locator("button.state").text_content() == "failed"
            assert "no speech synthesizer" in await row.text_content()
            assert await page.locator('section[data-package="tiny-speaker"] tr[data-robot-type="nao"] '
                                      'button.state').text_content() == "passed"
            assert await page.locator('section[data-package="echo-app"] button.untested').count() == 2
            await row.locator("button.state").click()
            await page.wait_for_function("document.querySelector('#log').textContent.includes('1 failed')")
            assert "tiny-speaker 1.0.0 for elektron" in await page.text_content("#log-title")
            assert problems == []
        finally:
            await page_server.stop()
    trace = [r for r in (tmp_path / "trace.jsonl").read_text().splitlines() if '"event": "build"' in r]
    assert len(trace) == 4  # each type's build began and ended
    # the builds and their logs survive the Store (its data directory)
    repo = StoreRepository(tmp_path / "run" / "store")
    try:
        assert {b.robot_type: b.state for b in repo.builds("tiny-speaker")} == {"elektron": "failed", "nao": "passed"}
        assert "no speech synthesizer" in repo.build_log("tiny-speaker", "1.0.0", "elektron")
    finally:
        repo.close()


def test_a_store_from_before_builds_lists_what_it_had_and_sources_that_do_not_compile_fail(tmp_path):
    old = tmp_path / "old"
    old.mkdir()
    db = sqlite3.connect(old / "store.db")
    db.executescript(_SCHEMA + "; PRAGMA user_version = 1;")
    db.close()
    with StoreRepository(old) as repo:  # migrated to version 2: builds kept from now on
        assert repo._db.execute("PRAGMA user_version").fetchone()[0] == len(MIGRATIONS) == 2
        repo.register_owner("dev", password="pw")
        repo.publish("dev", build_package_bytes(tiny_rapp(tmp_path, tests=False)))  # no builds given: untested
        assert [p.robot_types for p in repo.list("elektron")] == [["nao", "elektron"]]
    from agents.store_build import compile_sources
    broken = tiny_rapp(tmp_path / "broken")
    (broken / "tiny_speaker" / "task.py").write_text("def oops(:\n")
    assert compile_sources(broken)[0].startswith("tiny_speaker/task.py: SyntaxError")


async def test_a_store_that_requires_tests_refuses_a_package_without(tmp_path):
    from agents.errors import RequestRefused

    async with RappSystem(tmp_path / "run", store_kw={"build": True, "require_tests": True}) as system:
        with pytest.raises(RequestRefused, match="has no tests"):
            await system.publish(tiny_rapp(tmp_path, tests=False))


def test_rapp_test_runs_a_rapps_tests_for_one_robot_type(tmp_path):
    import subprocess

    from .test_cli import RAPP

    src = tiny_rapp(tmp_path)
    run = [*RAPP, "test", str(src), "-k", "can_speak", "--robot"]
    nao = subprocess.run([*run, "nao"], capture_output=True, text=True, cwd=tmp_path, timeout=120,
                         stdin=subprocess.DEVNULL)
    elektron = subprocess.run([*run, "elektron"], capture_output=True, text=True, cwd=tmp_path, timeout=120,
                              stdin=subprocess.DEVNULL)
    assert nao.returncode == 0 and "1 passed" in nao.stdout, nao.stdout[-2000:]
    assert elektron.returncode == 1 and "an elektron has no speech synthesizer" in elektron.stdout, elektron.stdout[-2000:]

