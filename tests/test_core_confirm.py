"""The Core's confirmation of a schedule heard by voice (agents/core_confirm.py), its answers heard
by real pocketsphinx on eSpeak NG recordings cut by the Core's voice activity detector
(hearing/answers.py); the Core around it is the Core's own hearing member with a plain host (the
agents' run is tests/test_core_speech.py's)."""
from __future__ import annotations

import asyncio
from types import SimpleNamespace

import numpy as np
import pytest

from agents.core_confirm import Confirmation, said_back
from agents.core_hearing import CoreHearing
from agents.scheduler import ScheduleDeclined
from bench.speech_offline import heard_utterances
from hearing import tts
from hearing.answers import AnswerSpotter, answer_meaning

STORE = ["forecast", "weather", "email", "game", "check my inbox", "tell me the forecast", "let's play a game"]
SPOTTER = AnswerSpotter(STORE)  # one for the module, as the Core keeps one (its decoders per thread)


def _heard(text: str, voice: str = "en-us", distance: float = 1.0):
    (utterance,) = heard_utterances(tts.synthesize(text, voice), distance)  # the speech bench's house, quiet
    return utterance


@pytest.mark.parametrize("said, voice, distance, meaning", [
    ("yes", "en-us+f3", 1.0, "yes"), ("yeah", "en", 2.0, "yes"), ("no", "en-us+m3", 1.0, "no"),
    ("no thanks", "en+f2", 0.5, "no"), ("cancel", "en-us", 2.0, "no"),
    ("forecast", "en-us", 1.0, None), ("open the window please", "en-us+f3", 1.0, None),
    ("I know", "en-us", 1.0, None)])
def test_yes_and_no_are_heard_and_other_speech_is_neither(said, voice, distance, meaning):
    assert SPOTTER.spot(_heard(said, voice, distance)) == meaning


def test_typed_answers_and_the_words_said_back():
    assert [answer_meaning(t) for t in ("Yes!", "no.", "Nope", "yes please", "don’t", "maybe", "yes no")] == \
        ["yes", "no", "no", "yes", "no", None, None]
    assert said_back("check my inbox every day at ten p m") == "check your inbox every day at ten p.m."
    assert said_back("read my e mail tomorrow at seven a m") == "read your e-mail tomorrow at seven a.m."
    assert said_back("do i have new mail in ten minutes") == 'schedule "do you have new mail in ten minutes"'


class Host:
    """The Core as a Confirmation and its hearing see it, outside s3 (in s4c)."""

    listening = False

    def __init__(self):
        self.told: list[str] = []
        self.records: list[tuple[str, dict]] = []
        self.robot = SimpleNamespace(capabilities=lambda: {"microphone"})

    async def tell_user(self, text, speak=True, label=""):
        self.told.append(text)

    def speaking(self):
        return False

    def record_structure(self, event, **fields):
        self.records.append((event, fields))


async def _ask(answers: list, answer_s: float = 0.5):
    """Confirmation.ask, the owner's answers to each question given as heard (None: nothing said)."""
    host = Host()
    hearing = CoreHearing(host, supervision={})
    hearing.answers = SPOTTER
    confirmation = Confirmation(host, hearing, answer_s=answer_s)

    async def owner():
        for heard in answers:
            while hearing._answer is None:  # the question is asked: its answer awaited
                await asyncio.sleep(0.01)
            if heard is None:  # silence: the answer's time ends
                while hearing._answer is not None:
                    await asyncio.sleep(0.01)
            else:
                await hearing.heard(heard)
                while hearing._answer is not None:
                    await asyncio.sleep(0.01)

    speaking = asyncio.ensure_future(owner())
    try:
        await confirmation.ask("check my inbox in ten minutes")
        return host, None
    except ScheduleDeclined as e:
        return host, e
    finally:
        speaking.cancel()


async def test_yes_confirms_at_once():
    host, declined = await _ask([_heard("yes", "en-us+m3")])
    assert declined is None and host.told == ["Shall I check your inbox in ten minutes? Say yes or no."]
    assert [f["answer"] for e, f in host.records if e == "schedule-answer"] == ["yes"]


async def test_garbage_then_silence_asks_once_more_then_drops_with_the_reason():
    rng = np.random.default_rng(3)
    burst = np.concatenate([np.zeros(64000), rng.normal(0, 3000, 16000), np.zeros(16000)]).astype(np.int16)
    garbage = heard_utterances(burst, 1.0)  # a bang of noise, cut as the Core cuts speech
    assert garbage
    host, declined = await _ask([garbage[0], None])
    assert declined is not None and host.told == [
        "Shall I check your inbox in ten minutes? Say yes or no.",
        "Sorry, I did not hear yes or no. Shall I check your inbox in ten minutes? Say yes or no."]
    assert declined.told == "I did not hear yes or no, so I have not scheduled it."
    assert str(declined) == "no yes or no heard, asked 2 times"
    assert [(f["answer"], f["by"]) for e, f in host.records if e == "schedule-answer"] == [("", "voice"), ("", "none")]


async def test_no_drops_and_a_typed_answer_counts_as_one():
    host, declined = await _ask([_heard("no", "en")])
    assert declined is not None and declined.told == "All right, I have not scheduled it."
    host = Host()
    confirmation = Confirmation(host, CoreHearing(host, supervision={}), answer_s=5.0)
    asking = asyncio.ensure_future(confirmation.ask("check my inbox in ten minutes"))
    while not confirmation.pending:
        await asyncio.sleep(0.01)
    assert not confirmation.take_typed("what is scheduled")  # not an answer: a command, queued as ever
    assert confirmation.take_typed("Yes.")
    await asking
    assert [f["by"] for e, f in host.records if e == "schedule-answer"] == ["chat"]


async def test_the_exchanges_time_out_names_the_questions_asked():
    host = Host()
    confirmation = Confirmation(host, CoreHearing(host, supervision={}), answer_s=5.0, timeout_s=0.3)
    with pytest.raises(ScheduleDeclined, match="^no yes or no heard, asked 1 time$"):
        await confirmation.ask("check my inbox in ten minutes")
    assert not confirmation.pending


async def test_a_typed_stop_or_cancel_during_the_question_still_stops_the_robot():
    """'cancel' is a no-word of the answers, but typed in the chat it latches the emergency stop as
    ever (the Core's _command_heard asks the stop words first); a typed yes answers the question."""
    from agents.core_agent import CoreAgent

    host = Host()
    confirmation = Confirmation(host, CoreHearing(host, supervision={}), answer_s=5.0)
    stops: list[str] = []
    queued: list[str] = []

    async def emergency_stop(reason):
        stops.append(reason)

    async def put(text):
        queued.append(text)

    core = SimpleNamespace(record_structure=lambda *a, **k: None, confirmation=confirmation,
                           robot_commands=SimpleNamespace(emergency_stop=emergency_stop),
                           commands=SimpleNamespace(put=put))
    asking = asyncio.ensure_future(confirmation.ask("check my inbox in ten minutes"))
    while not confirmation.pending:
        await asyncio.sleep(0.01)
    await CoreAgent._command_heard(core, "Cancel!")
    assert stops == ["stopped by the user"] and confirmation.pending
    await CoreAgent._command_heard(core, "yes")
    await asking
    assert queued == [] and stops == ["stopped by the user"]
