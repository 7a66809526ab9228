"""The owner's answer to a yes-or-no question the robot asked (the Core's confirmation of a schedule
heard by voice, agents/core_confirm.py): "yes", "no", or not understood.

    answers = AnswerSpotter(competitors)   # the Store's keywords and phrases compete
    answers.spot(utterance)                # "yes", "no" or None (CPU work: call from an executor)
    answer_meaning("Yes please!")          # a typed answer: "yes", "no" or None

A few words only, each taken by the keyword rule of hearing/keywords.py (its path beats the free
phone loop by ACCEPT, said alone, no close runner-up of the other meaning). Anything else said, a
command among them, competes and is no answer: the question is asked again rather than guessed.
What it was measured on: docs/sound.md, "A schedule heard by voice is confirmed".
"""
from __future__ import annotations

from typing import Sequence

from .decoder import normalize
from .keywords import ACCEPT, KeywordSpotter
from .vad import HeardUtterance

YES_WORDS = ("yes", "yeah", "yes please", "okay")
NO_WORDS = ("no", "nope", "no thanks", "cancel", "cancel it", "don't")
MEANING = {**{w: "yes" for w in YES_WORDS}, **{w: "no" for w in NO_WORDS}}


class AnswerSpotter:
    """Yes or no in one utterance; `competitors`: other phrases the owner may say instead (the
    Store's keywords and command phrases), so a command is heard as the command it is and not
    squeezed into "no". Decoders per thread (KeywordSpotter)."""

    def __init__(self, competitors: Sequence[str] = (), accept: float = ACCEPT):
        others = [c for c in competitors if normalize(c) not in MEANING]
        self.spotter = KeywordSpotter(sorted(MEANING), others, groups=MEANING, accept=accept)

    def spot(self, utterance: HeardUtterance) -> str | None:
        word = self.spotter.spot(utterance)
        return MEANING.get(normalize(word)) if word else None


def answer_meaning(text: str) -> str | None:
    """A typed answer's meaning: "yes", "no", or None (not one of the answer words, said alone)."""
    return MEANING.get(normalize(text.replace("\u2019", "'")))
