"""The Core's spoken confirmation of a schedule heard by voice (s4c, agents/core_fsm.py).

Heard speech is misheard where typed text is not: on eSpeak NG's voices the Platform's search took
"play a game with me now" for "play a game in three hours" in 4 of 6 recordings, and heard "seven a m"
as "ten a m" (docs/sound.md, "Schedules said aloud"). So a new schedule heard by voice is kept only
when the owner says yes to what the Core understood:

    "Shall I check the hazards every day at ten p.m.? Say yes or no."
      yes -> kept (the scheduler says "I will run ...")
      no  -> dropped: "All right, I have not scheduled it."
      nothing, or neither word -> asked once more, then dropped: "I did not hear yes or no, ..."

The answer is heard by hearing/answers.py (a few yes / no words, the Store's words competing), in
the first utterance the owner begins within `answer_s` of sound after the question; "yes" or "no"
typed in the chat answers too. The whole exchange takes at most `timeout_s`: the Core's FSM waits in
s4c meanwhile, and commands that come then wait in its queue as they do in s4-s6 (a schedule come due
too; LATE_S is far longer), while "stop" still latches the emergency stop at once.
A schedule typed in the chat is kept without a question: text is not misheard.
"""
from __future__ import annotations

import asyncio
import logging
import re
from typing import TYPE_CHECKING, Any, Protocol

from hearing.answers import answer_meaning

from .scheduler import ScheduleDeclined

if TYPE_CHECKING:
    from .core_hearing import CoreHearing

log = logging.getLogger("rapp.core")
ANSWER_S = 6.0  # of sound after the question: the owner's time to begin an answer
ASKS = 2  # the question, and once more after no answer or an unclear one
TIMEOUT_S = 40.0  # wall clock, the whole exchange (two questions said, two answers awaited)
QUESTION_WORDS = {"do", "does", "is", "are", "will", "can", "what", "what's", "where", "when", "how", "who"}


class ConfirmHost(Protocol):
    """What a Confirmation needs of the Core: its chat and loudspeaker, and its records."""

    async def tell_user(self, text: str, speak: bool = True, label: str = "") -> None: ...

    def speaking(self) -> bool: ...

    def record_structure(self, event: str, **fields: Any) -> None: ...


class Confirmation:
    """Asks the owner to confirm words heard (`ask`); `take_typed` gives it an answer typed in the chat."""

    def __init__(self, host: ConfirmHost, hearing: CoreHearing, answer_s: float = ANSWER_S,
                 timeout_s: float = TIMEOUT_S):
        self.host, self.hearing = host, hearing
        self.answer_s, self.timeout_s = answer_s, timeout_s
        self._typed: asyncio.Future[str] | None = None
        self.asked = 0  # questions of the exchange in hand said so far

    @property
    def pending(self) -> bool:
        """A question waits for its answer."""
        return self._typed is not None and not self._typed.done()

    def take_typed(self, text: str) -> bool:
        """An answer typed while a question waits: True when taken as the answer."""
        meaning = answer_meaning(text)
        if meaning is None or not self.pending:
            return False
        self._typed.set_result(meaning)
        return True

    async def ask(self, words: str) -> None:
        """Returns when the owner said yes; ScheduleDeclined (with what to tell them) otherwise."""
        question = f"Shall I {said_back(words)}?"
        self.asked = 0
        try:
            answer = await asyncio.wait_for(self._exchange(question), self.timeout_s)
        except asyncio.TimeoutError:
            answer = None
        finally:
            self._typed = None
        if answer == "no":
            raise ScheduleDeclined("the owner said no", "All right, I have not scheduled it.")
        if answer != "yes":
            raise ScheduleDeclined(f"no yes or no heard, asked {self.asked} time{'s' * (self.asked != 1)}",
                                   "I did not hear yes or no, so I have not scheduled it.")

    async def _exchange(self, question: str) -> str | None:
        for n in range(1, ASKS + 1):
            self.asked = n
            self._typed = asyncio.get_running_loop().create_future()
            self.host.record_structure("schedule-asked", question=question[:200], ask=n)
            await self.host.tell_user(("" if n == 1 else "Sorry, I did not hear yes or no. ")
                                      + f"{question} Say yes or no.")
            answer, by = await self._answer()
            self.host.record_structure("schedule-answer", answer=answer or "", by=by, ask=n)
            if answer is not None:
                return answer
        return None

    async def _answer(self) -> tuple[str | None, str]:
        """(yes / no / None, how it came: voice, chat or none) for the question just told."""
        typed = self._typed
        voice = asyncio.ensure_future(self._voice_answer())
        try:
            await asyncio.wait({typed, voice}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            voice.cancel()
        if typed.done():
            return typed.result(), "chat"
        if voice.exception() is not None:  # the recogniser failed: as nothing heard (asked again)
            log.warning("hearing the owner's answer failed: %r", voice.exception())
            return None, "none"
        heard, said = voice.result()
        return heard, "voice" if said else "none"

    async def _voice_answer(self) -> tuple[str | None, bool]:
        """(meaning, whether anything was said): the owner's first utterance after the question."""
        while self.host.speaking():  # the question is still being said: the answer comes after it
            await asyncio.sleep(0.05)
        utterance = await self.hearing.hear_answer(self.answer_s)
        if utterance is None:
            return None, False
        return await self.hearing.spot_answer(utterance), True


def said_back(words: str) -> str:
    """The owner's words as the robot says them back: "check my inbox at ten p m" -> "check your inbox
    at ten p.m."; a question ("do i have new mail ...") is quoted: 'schedule "do you have ..."'."""
    swap = {"me": "you", "my": "your", "i": "you", "i'm": "you're", "mine": "yours"}
    said = [swap.get(w, w) for w in words.lower().split()]
    text = re.sub(r"\b([ap]) m\b", r"\1.m.", " ".join(said)).replace("e mail", "e-mail")  # as the grammar spells them
    return f'schedule "{text}"' if said and said[0] in QUESTION_WORDS else text
