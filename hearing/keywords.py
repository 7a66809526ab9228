"""Keywords: whether what was heard is one of a few known words or short phrases, said alone.

    spotter = KeywordSpotter(keywords, phrases, groups)   # the Core's commands (s4a)
    word = spotter.spot(utterance)                        # the keyword said, or None
    keyword_in_a_sentence(reply, keywords, utterance)     # the Platform's answer: a keyword inside a sentence?
    WordSpotter(words).spot(pcm)                          # a RApp's words (the robot's word_spotting)
    ahead = LookAhead(); ahead.start(spotter, utterance)  # spotting begun before the detector's cut

Every keyword decision here, the owner's commands (s4a), the supervision words during a task and a
RApp's word spotting, takes a keyword by one rule: its path, aligned alone to the audio, scores at
least ACCEPT against a free phone loop (decoder.PhraseDecoder: the owner said the keyword, not
something else). What else each asks is said where it is asked: said alone (said_alone, `min_cover`),
no close runner-up meaning something else (MIN_LEAD), the search's own answer trusted (WordSpotter).
What ACCEPT was measured on: docs/sound.md, "Keywords".
"""
from __future__ import annotations

import asyncio
import logging
import threading
from typing import TYPE_CHECKING, Container, Sequence

import numpy as np

from .decoder import PhraseDecoder, normalize
from .vad import HeardUtterance, frame_levels

if TYPE_CHECKING:
    from ontology.services.speech import Recognition

# how far a keyword's path may score below the free phone loop's (log-score per second), for every
# keyword spotted here: keywords said alone in a quiet room score a little below it, and a stricter
# bound refused them where nothing else would have heard them (a "stop" beside a TV too); most other
# speech forced onto a keyword scores lower (docs/sound.md, "Keywords")
ACCEPT = -0.04


class KeywordSpotter:
    """Is an utterance one of `keywords`, said alone? A grammar of the keywords and the command phrases
    (so a sentence is recognised as the sentence it is, not squeezed into a keyword), the best complete
    phrase checked against a free phone loop (PhraseDecoder), and a keyword taken only when it covers
    most of the speech the detector heard (`min_cover`: one word of a sentence is not said alone).
    Decoders are per thread (pocketsphinx is not thread-safe) and kept (building one takes ~90 ms of
    the 500 ms budget).
    `groups` (keyword -> its RApp) lets a close runner-up that means the same (hazard / hazards) pass;
    a runner-up of another group closer than MIN_LEAD is not understood rather than guessed."""

    MAX_KEYWORD_SECONDS = 1.6  # of speech: longer is a sentence, whatever it sounds like
    MIN_LEAD = 0.01  # log-score per second over a runner-up keyword of another group
    # a keyword said alone is most of the speech heard: the keyword's aligned words cover at least this
    # share of the detector's speech seconds, less the echo after them (said_alone); a word of a
    # sentence covers less. The supervision words ask 0: "stop, stop!" stops the robot
    MIN_COVER = 0.75

    def __init__(self, keywords: list[str], phrases: Sequence[str] = (), groups: dict[str, str] | None = None,
                 accept: float = ACCEPT, min_cover: float = MIN_COVER):
        # accept: ACCEPT but for a threshold under test (bench/speech_offline.py --accept)
        self.accept, self.min_cover = accept, min_cover
        self.keywords = {normalize(k): k for k in keywords if normalize(k)}
        self.phrases = [p for p in dict.fromkeys(normalize(p) for p in phrases) if p and p not in self.keywords]
        self.groups = {normalize(k): g for k, g in (groups or {}).items()}
        self._decoders: dict[int, PhraseDecoder] = {}
        self._lock = threading.Lock()

    def _decoder(self) -> PhraseDecoder:
        key = threading.get_ident()
        with self._lock:
            dec = self._decoders.get(key)
        if dec is None:
            dec = PhraseDecoder(list(self.keywords) + self.phrases)
            with self._lock:
                self._decoders[key] = dec
        return dec

    def warm_up(self) -> None:
        self._decoder()

    def spot(self, utterance: HeardUtterance) -> str | None:
        """The keyword said (as given), or None: not a keyword alone (CPU work: call from an executor)."""
        if not self.keywords or utterance.speech_seconds > self.MAX_KEYWORD_SECONDS:
            return None
        dec = self._decoder()
        heard, _ = dec.decode(utterance.pcm, accept=self.accept)
        if heard is None or heard not in self.keywords:
            return None
        if not said_alone(utterance, [(first, last) for w, first, last in dec.segments if w[:1] not in "<["],
                          self.min_cover):
            return None  # one word of something longer: the Platform hears it whole (s4b)
        other = dec.runner_up
        if other is not None and dec.lead < self.MIN_LEAD and self._group(other) != self._group(heard):
            return None  # two different commands fit about equally well: ask again rather than guess
        return self.keywords[heard]

    def _group(self, words: str) -> str:
        return self.groups.get(words, words)



ECHO_DB = 15.0  # this far below the words' loudest 10 ms, the speech after them is the room's echo of them
MAX_OTHER_SPEECH_S = 0.1  # of the detector's speech outside a keyword said alone (less its echo)


def said_alone(utterance: HeardUtterance, words: list[tuple[int, int]], share: float = KeywordSpotter.MIN_COVER) -> bool:
    """Whether `words` (first and last 10 ms frame of each, in the utterance's audio) are what the
    utterance said, and not one part of something longer: they cover `share` of the speech the
    detector heard in it, and leave at most MAX_OTHER_SPEECH_S of that speech outside them. In a
    furnished room the detector hears a word's echo as speech for a few hundred ms after it; the
    speech after the words quieter than their loudest frame by ECHO_DB is that echo, not more words,
    and is not counted (docs/sound.md, "Keywords"). `share` 0: any words will do ("stop, stop!")."""
    if not words:
        return False
    if share <= 0:
        return True
    first, last = min(f for f, _ in words), max(la for _, la in words)
    echo = echo_seconds(utterance, first, last)
    said = sum(la - f + 1 for f, la in words) / 100
    if said < share * max(utterance.speech_seconds - echo, 0.01):
        return False
    if utterance.loud is None:
        return True
    loud = utterance.loud[:len(utterance.pcm) // 160]
    inside = sum(int(np.count_nonzero(loud[f:la + 1])) for f, la in words)
    return bool((np.count_nonzero(loud) - inside) / 100 - echo <= MAX_OTHER_SPEECH_S)


def echo_seconds(utterance: HeardUtterance, first: int, last: int) -> float:
    """Speech the detector heard after frame `last` ECHO_DB or more below the loudest frame of
    `first`..`last`: the room's echo of those words (0 when the utterance has no loud frames kept)."""
    loud = utterance.loud
    n = 0 if loud is None else min(len(loud), len(utterance.pcm) // 160)
    if loud is None or first >= n or last < first:
        return 0.0
    level = frame_levels(utterance.pcm[:n * 160].reshape(n, 160))
    loudest = level[first:last + 1].max()
    after = slice(last + 1, n)
    return float(np.count_nonzero(loud[after] & (level[after] < loudest - ECHO_DB))) / 100


def keyword_in_a_sentence(reply: "Recognition", keywords: Container[str], utterance: HeardUtterance) -> bool:
    """Whether the Platform's answer is a bare keyword (one of `keywords`, normalized) that covers too
    little of the utterance's speech to have been said alone (said_alone, the keyword spotter's rule):
    one word of a sentence, which the general model should hear whole."""
    words = [(round(w.start * 100), round(w.end * 100) - 1) for w in reply.words]  # its 10 ms frames
    return normalize(reply.text) in keywords and not said_alone(utterance, words)


class WordSpotter:
    """A RApp's words (the robot's word_spotting), in a stretch of speech cut by level alone: a grammar
    of them alone, the search's own complete answer trusted (PhraseDecoder `trust_search`: a number
    said alone must not lose to a longer one aligned alone), taken at ACCEPT. Not thread-safe: one per
    listener."""

    def __init__(self, words: list[str], accept: float = ACCEPT):
        self.decoder, self.accept = PhraseDecoder(words, trust_search=True), accept
        self._as_given = {normalize(w): w for w in words}

    @property
    def knows_any(self) -> bool:
        """Whether the recogniser can hear any of the words at all."""
        return bool(self.decoder.phrases)

    def spot(self, pcm: np.ndarray) -> tuple[str | None, str | None]:
        """(the word as given, what was heard) in one stretch of speech, or (None, None) (CPU work)."""
        heard, _ = self.decoder.decode(pcm, self.accept)
        if heard is None:
            return None, None
        return self._as_given.get(heard, heard), heard


class LookAhead:
    """The keyword spotter run on the utterance the detector will cut unless the owner goes on, from
    the moment its audio is fixed (`pad`, 0.2 s, of silence) rather than at the cut (0.3 s): the
    spotting (50-100 ms of CPU) then overlaps the last 0.1 s of silence, in the keyword path's
    500 ms. The cut takes the early answer only when it is the same audio, so the answer is the one
    the cut would get; an owner who goes on costs the early work only.

        ahead = LookAhead()
        ahead.start(spotter, utterance)       # the utterance the detector is about to cut (VoiceActivity.ending)
        word, early = await ahead.spot(spotter, utterance)  # the cut: the early answer when it is the same
    """

    def __init__(self) -> None:
        self._pending: tuple[HeardUtterance, KeywordSpotter, asyncio.Future[str | None]] | None = None

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


def _quietly(future: asyncio.Future[str | None]) -> None:
    """An early answer nobody takes: its failure is logged, not left unretrieved."""
    if not future.cancelled() and future.exception() is not None:
        logging.getLogger("rapp.core").debug("early keyword spotting failed: %r", future.exception())
