"""The reference RApps (weather reporter, news explorer, e-mail reader, cognitive game) run on the same Core,
unchanged, each started by a user sentence interpreted by the Platform."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from ontology import platform as P
from ontology.services.email import EmailSend
from ontology.services.knowledge import GetHistory
from robots import RobotAPI, World
from scenarios.system import RappSystem

from .test_lifecycle import wait_until

RAPPS = Path(__file__).resolve().parent.parent / "rapps"


@pytest.fixture(scope="module")
async def system(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("reference")
    world = World.from_file("small", seed=9)
    async with RappSystem(workdir, trace_file=workdir / "trace.jsonl") as system:
        for name in ("weather_reporter", "email_reader", "cognitive_game", "news_explorer"):
            await system.publish(RAPPS / name)
        system.world = world
        system.nao = world.add_robot("nao")
        system.handle = await system.add_robot("nao", api=RobotAPI(system.nao))
        await wait_until(lambda: len(system.handle.core.vocabulary) >= 4 and system.handle.core.listening)
        core = system.handle.core
        login = await system.publisher.request(system.platform.address,
                                               P.Login(user=core.user, password=core.password))
        system.token = login.token  # the owner's own token, as their phone app would have it
        yield system
    world.close()


async def command(system, text: str, expect: str, timeout: float = 60.0, handle=None) -> list[str]:
    handle = handle or system.handle
    core = handle.core  # the previous task may still be winding down: wait for supervision
    await wait_until(lambda: core.listening and "user-listener" in core.active_behaviours())
    user = handle.user
    start = len(user.received)
    await user.say(core.address, text)
    await user.wait_for(lambda t: expect in t, timeout=timeout, start=start)
    return [re.sub(r"^\[[^]]*\] ", "", t) for t in user.texts()[start:]]  # a RApp's words, their label off


async def test_weather_reporter(system):
    said = await command(system, "what's the weather in Warsaw", "weather_reporter finished")
    report = next(t for t in said if t.startswith("In Warsaw"))
    assert "12 degrees" in report and "partly cloudy" in report and "Tomorrow: light rain" in report
    assert any("In Warsaw" in t for _, t in system.nao.loudspeaker.spoken)  # it was spoken too


async def test_weather_reporter_writes_when_the_robot_cannot_speak(system):
    elektron = await system.add_robot("elektron", api=RobotAPI(system.world.add_robot("elektron")))
    await wait_until(lambda: len(elektron.core.vocabulary) >= 3 and elektron.core.listening)
    said = await command(system, "what's the weather in Krakow", "weather_reporter finished", handle=elektron)
    report = next(t for t in said if t.startswith("In Krakow"))
    assert "fog" in report and "cannot speak, so I wrote it" in report


async def test_news_explorer_reads_a_topic_or_the_stories_about_a_subject(system):
    said = await command(system, "tell me the news about health", "news_explorer finished")
    report = next(t for t in said if t.startswith("Here are 2 stories about health"))
    assert "1. Walking every day keeps the heart young." in report and "2. Flu season ends early" in report
    assert any("about health" in t for _, t in system.nao.loudspeaker.spoken)  # it was spoken too
    said = await command(system, "any news about the orchestra", "news_explorer finished")
    assert any(t.startswith("Here is one story about orchestra. 1. Orchestra plays free concert") for t in said), said
    said = await command(system, "what's new in gardening", "news_explorer finished")
    assert any(t.startswith("I found no news about gardening.") for t in said), said


async def test_email_reader(system):
    said = await command(system, "read my e-mail", "email_reader finished")
    assert any("no new e-mail" in t for t in said)
    await system.publisher.request(system.platform.address, EmailSend(
        token=system.token, recipients=[system.handle.core.user], subject="Dinner on Sunday",
        body="Come at six, bring the cake."))
    said = await command(system, "do I have new mail?", "email_reader finished")
    assert any("Dinner on Sunday" in t and "bring the cake" in t for t in said)


async def test_cognitive_game_hears_answers_and_records_score(system):
    user, mic = system.handle.user, system.nao.microphone
    start = len(user.received)
    await user.say(system.handle.core.address, "let's play a game")
    answers = {"How much is 2 plus 3?": "five", "How much is 10 minus 4?": "I think it is 6",
               "How much is 7 times 8?": "56", "How much is 45 divided by 5?": "nine"}
    asked = 0
    while True:
        text = await user.wait_for(lambda t: "] Question" in t or "finished:" in t,
                                   timeout=60, start=start)
        start = user.received.index(next(r for r in user.received[start:] if r[2] == text)) + 1
        if "finished:" in text:
            break
        question = re.sub(r"^\[[^]]*\] Question \d+: ", "", text)  # a RApp's words come labelled
        mic.hear(answers.get(question, "pass"))
        asked += 1
    assert asked >= 2 and f"{asked} of {asked} correct, score 100" in text
    await user.wait_for(lambda t: "cognitive_game finished" in t, timeout=30, start=start)
    history = await system.publisher.request(system.platform.address, GetHistory(token=system.token))
    assert history.records and history.records[-1].score == 100.0


async def test_hello_example(system):
    await system.publish(RAPPS / "examples" / "hello")
    core = system.handle.core
    core.vocabulary["hello"] = "hello"  # published after the Core read the Store's list
    said = await command(system, "hello", "hello finished")
    assert "Hello, I am your robot." in said
