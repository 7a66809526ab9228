"""A sentence the owner pauses in (s4b for speech).

The Core's voice detector ends an utterance after 0.3 s of silence: the keyword path's 500 ms
budget allows no longer. A sentence said with a longer breath in it ("what's the weather ... in
Warsaw") then arrives in two parts; each alone is misheard, or means less (the city is lost).
While the Platform recognises the first part, the Core listens on: speech that starts again within
CONTINUE_WITHIN_S of sound after the cut continues the sentence, and the two parts are recognised
as one. Time is the microphone's (the sound fed to the detector), so a simulated world run faster
than real time waits as long in its own seconds.

    continuation = Continuation(vad)      # the detector of the Core's listening (s3)
    continuation.offer(utterance)         # each utterance heard outside s3: True when awaited
    more = await continuation.after()     # in s4b: the next part, or None

A keyword spotted ahead of the cut (s4a for speech, LookAhead):

    ahead = LookAhead()
    ahead.start(spotter, utterance)       # the utterance the detector is about to cut (VoiceActivity.ending)
    word, early = await ahead.spot(spotter, utterance)  # the cut: the early answer when it is the same

Also here: whether the Platform's answer is a keyword heard inside a sentence (keyword_in_a_sentence).
"""
from __future__ import annotations

import asyncio
import logging
import time

import numpy as np

from ontology.services.speech import Recognition
from robots.receptors import HeardUtterance, KeywordSpotter, VoiceActivity, normalize, said_alone

CONTINUE_WITHIN_S = 0.5  # of sound after the cut: with the detector's 0.3 s, pauses up to 0.8 s
MAX_WAIT_S = 8.0  # wall clock, for the next part to end (the detector cuts an utterance at 5 s)
STALL_S = 1.0  # wall clock with no new sound: nobody feeds the detector (the listener stopped)


class Continuation:
    def __init__(self, vad: VoiceActivity):
        self.vad = vad
        self._awaited: asyncio.Future | None = None

    @property
    def owner_speaking(self) -> bool:
        """The owner is saying something now (an utterance the detector has not cut yet)."""
        return self.vad.active

    def offer(self, utterance: HeardUtterance) -> bool:
        """Take `utterance` as the next part awaited, if one is; True when taken."""
        awaited = self._awaited
        if awaited is None or awaited.done():
            return False
        awaited.set_result(utterance)
        return True

    async def after(self, poll_s: float = 0.02) -> HeardUtterance | None:
        """What the owner says next, when they go on within CONTINUE_WITHIN_S of the last cut."""
        vad, cut = self.vad, self.vad.cut_s
        if cut is None:
            return None
        awaited = self._awaited = asyncio.get_running_loop().create_future()
        try:
            heard, since = vad.heard_s, time.monotonic()
            while not self.owner_speaking and not awaited.done():
                if vad.heard_s - cut >= CONTINUE_WITHIN_S:
                    return None
                if vad.heard_s != heard:
                    heard, since = vad.heard_s, time.monotonic()
                elif time.monotonic() - since > STALL_S:
                    return None
                await asyncio.sleep(poll_s)
            more = await asyncio.wait_for(asyncio.shield(awaited), MAX_WAIT_S)
            return None if more.too_long else more
        except asyncio.TimeoutError:
            return None
        finally:
            self._awaited = None


class LookAhead:
    """The keyword spotter run on the utterance the detector will cut unless the owner goes on, from
    the moment its audio is fixed (`pad`, 0.2 s, of silence) rather than at the cut (0.3 s): the
    spotting (50-100 ms of CPU) then overlaps the last 0.1 s of silence, in the keyword path's
    500 ms. The cut takes the early answer only when it is the same audio, so the answer is the one
    the cut would get; an owner who goes on costs the early work only."""

    def __init__(self):
        self._pending: tuple[HeardUtterance, KeywordSpotter, asyncio.Future] | None = None

    def start(self, spotter: KeywordSpotter, utterance: HeardUtterance) -> None:
        if utterance.too_long or utterance.speech_seconds > spotter.MAX_KEYWORD_SECONDS:
            return  # a sentence: spot() answers None at once
        future = asyncio.get_running_loop().run_in_executor(None, spotter.spot, utterance)
        future.add_done_callback(_quietly)
        self._pending = (utterance, spotter, future)

    async def spot(self, spotter: KeywordSpotter, utterance: HeardUtterance) -> tuple[str | None, bool]:
        """(spotter.spot(utterance), whether it was answered early)."""
        pending, self._pending = self._pending, None
        if pending is not None and pending[1] is spotter and _same(pending[0], utterance):
            return await pending[2], True
        return await asyncio.get_running_loop().run_in_executor(None, spotter.spot, utterance), False


def _same(a: HeardUtterance, b: HeardUtterance) -> bool:
    return a is b or (a.end_sample == b.end_sample and a.speech_seconds == b.speech_seconds
                      and np.array_equal(a.pcm, b.pcm))


def _quietly(future: asyncio.Future) -> None:
    """An early answer nobody takes: its failure is logged, not left unretrieved."""
    if not future.cancelled() and future.exception() is not None:
        logging.getLogger("rapp.core").debug("early keyword spotting failed: %r", future.exception())


def keyword_in_a_sentence(reply: Recognition, keywords, utterance: HeardUtterance) -> bool:
    """Whether the Platform's answer is a bare keyword (one of `keywords`, normalized) that covers too
    little of the utterance's speech to have been said alone (robots/receptors.py said_alone, the
    keyword spotter's rule): one word of a sentence, which the general model should hear whole."""
    words = [(round(w.start * 100), round(w.end * 100) - 1) for w in reply.words]  # its 10 ms frames
    return normalize(reply.text) in keywords and not said_alone(utterance, words)
