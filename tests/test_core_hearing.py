"""A sentence the owner pauses in (agents/core_hearing.py): the voice detector cuts it at the pause,
and the Core takes the next part as its continuation only when speech starts again soon enough. And
the keyword spotted ahead of the detector's cut (hearing/keywords.py LookAhead)."""
from __future__ import annotations

import asyncio

import numpy as np
import pytest

from agents import core_hearing
from agents.core_hearing import CONTINUE_WITHIN_S, Continuation
from hearing import tts
from hearing.keywords import LookAhead
from hearing.vad import VoiceActivity

RATE = 16000


def _said(*parts, pause_s: float) -> np.ndarray:
    """The room's sound (1 s first, for the detector to learn it), the parts said `pause_s` apart."""
    rng = np.random.default_rng(1)
    gap = np.zeros(int(pause_s * RATE))
    speech = [tts.synthesize(p, "en-us").astype(np.float64) for p in parts]
    body = np.concatenate([np.zeros(RATE)] + [x for s in speech for x in (s, gap)] + [np.zeros(RATE)])
    return np.clip(body + rng.normal(0, 30, len(body)), -32768, 32767).astype(np.int16)


async def _listen(pcm, vad, continuation, first: list, chunk_s=0.1, stop_at=None):
    """Feed the detector as the Core's listener does: the first utterance is the command (s4a/s4b),
    any later one is offered as its continuation."""
    step = int(chunk_s * RATE)
    for i in range(0, len(pcm) if stop_at is None else int(stop_at * RATE), step):
        for u in vad.feed(pcm[i:i + step]):
            if not first:
                first.append(u)
            else:
                continuation.offer(u)
        await asyncio.sleep(0.005)


async def _continued(pcm, **kw):
    vad = VoiceActivity(max_seconds=5.0)
    continuation, first = Continuation(vad), []
    feeding = asyncio.create_task(_listen(pcm, vad, continuation, first, **kw))
    while not first and not feeding.done():
        await asyncio.sleep(0.001)
    assert first, "the detector heard nothing"
    t0 = asyncio.get_running_loop().time()
    more = await continuation.after()
    _continued.waited = asyncio.get_running_loop().time() - t0
    await feeding
    return vad, first[0], more


async def test_speech_again_within_the_pause_continues_the_sentence():
    vad, first, more = await _continued(_said("what's the weather", "in warsaw", pause_s=0.6))
    assert more is not None and 0.2 < more.speech_seconds < 1.0
    whole = first.then(more)
    assert whole.seconds == pytest.approx(first.seconds + more.seconds)
    assert whole.speech_seconds == pytest.approx(first.speech_seconds + more.speech_seconds)
    # each 10 ms of the audio says whether the detector took it for speech (hearing/keywords.py said_alone)
    for u in (first, more, whole):
        assert len(u.loud) * 160 == len(u.pcm) and abs(u.loud.sum() / 100 - u.speech_seconds) <= 0.05
    assert not whole.loud[len(first.loud) - 5:len(first.loud)].any()  # the pause


async def test_a_longer_pause_is_two_utterances():
    _, _, more = await _continued(_said("what's the weather", "in warsaw", pause_s=0.3 + CONTINUE_WITHIN_S + 0.4))
    assert more is None


async def test_nobody_goes_on():
    vad, _, more = await _continued(_said("check my inbox", pause_s=0.0))
    assert more is None and vad.heard_s - vad.cut_s >= CONTINUE_WITHIN_S


async def test_a_listener_that_stops_feeding_is_not_waited_for(monkeypatch):
    monkeypatch.setattr(core_hearing, "STALL_S", 0.3)
    pcm = _said("check my inbox", pause_s=0.0)
    # the sound stops about 0.2 s after the cut (the detector cuts after 0.3 s of silence)
    vad, _, more = await _continued(pcm, stop_at=1.0 + len(tts.synthesize("check my inbox", "en-us")) / RATE + 0.5)
    assert more is None and vad.heard_s - vad.cut_s < CONTINUE_WITHIN_S  # given up for the stall, not the pause
    assert 0.3 <= _continued.waited < 0.8


def _endings_and_cuts(pcm, chunk_s=0.01):
    """Feed the detector `pcm`: (heard_s, what `ending` says) each time it changes, and (heard_s, cut)s."""
    vad, endings, cuts, step = VoiceActivity(max_seconds=5.0), [], [], int(chunk_s * RATE)
    for i in range(0, len(pcm), step):
        cuts += [(vad.heard_s + chunk_s, u) for u in vad.feed(pcm[i:i + step])]
        ending = vad.ending()
        if ending is not None and (not endings or endings[-1][1].end_sample != ending.end_sample):
            endings.append((vad.heard_s, ending))
    return endings, cuts


def test_the_utterance_about_to_be_cut_is_the_cut():
    endings, cuts = _endings_and_cuts(_said("check my inbox", pause_s=0.0))
    assert len(cuts) == 1 and len(endings) == 1
    (known_at, early), (cut_at, cut) = endings[0], cuts[0]
    assert 0.09 <= cut_at - known_at <= 0.11  # 0.1 s ahead: the detector's 0.3 s of silence less its 0.2 s pad
    assert np.array_equal(early.pcm, cut.pcm) and np.array_equal(early.loud, cut.loud)
    assert (early.end_sample, early.speech_seconds) == (cut.end_sample, cut.speech_seconds)


def test_an_owner_who_goes_on_makes_another_cut():
    # a pause longer than the pad and shorter than the detector's silence: an end foreseen, then speech again
    endings, cuts = _endings_and_cuts(_said("what's the", "weather", pause_s=0.25))
    assert len(cuts) == 1 and len(endings) == 2
    assert endings[0][1].seconds < cuts[0][1].seconds - 0.4
    assert np.array_equal(endings[1][1].pcm, cuts[0][1].pcm)


@pytest.fixture(scope="module")
def spotter():
    from hearing.keywords import KeywordSpotter
    return KeywordSpotter(["inbox", "weather"], ["what's the weather in warsaw"])


@pytest.mark.parametrize("said, pause_s, early", [(("inbox",), 0.0, True), (("what's the", "weather"), 0.25, False)])
async def test_the_keyword_spotted_ahead_is_taken_only_for_the_same_audio(spotter, said, pause_s, early):
    endings, cuts = _endings_and_cuts(_said(*said, pause_s=pause_s))
    ahead = LookAhead()
    ahead.start(spotter, endings[0][1])
    word, was_early = await ahead.spot(spotter, cuts[0][1])
    assert was_early is early
    assert word == spotter.spot(cuts[0][1])
    assert (word == "inbox") is (said == ("inbox",))


@pytest.mark.parametrize("resume_frames, cut_within", [(2, 0.45), (1, None)])
def test_a_click_alone_does_not_hold_the_utterance_open(resume_frames, cut_within):
    """A single loud 10 ms frame in the silence after speech is the room's (the microphone's own noise
    takes a frame for speech about once a second): the silence goes on; two in a row are speech again."""
    pcm = np.concatenate([_said("check my inbox", pause_s=0.0), _said(pause_s=0.0)]).astype(np.float64)
    spoken_until = 1.0 + len(tts.synthesize("check my inbox", "en-us")) / RATE
    first = (int(spoken_until * 100) + 5) * 160  # a frame of the detector's, 40-50 ms after the speech
    clicks = np.random.default_rng(2).normal(0, 80, 160)  # the room's sound, 8 dB louder for 10 ms
    for at in range(first, first + int(0.9 * RATE), 15 * 160):  # one every 0.15 s for 0.9 s
        pcm[at:at + 160] += clicks
    vad = VoiceActivity(max_seconds=5.0, resume_frames=resume_frames)
    cuts = [vad.heard_s + 0.01 for i in range(0, len(pcm), 160) if vad.feed(pcm[i:i + 160].astype(np.int16))]
    assert len(cuts) == 1
    if cut_within is not None:
        assert cuts[0] - spoken_until < cut_within
    else:  # each click held it open: cut 0.3 s after the last
        assert cuts[0] - spoken_until > 0.9
