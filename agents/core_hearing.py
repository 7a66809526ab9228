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

The rest of hearing is in the hearing/ package: the detector (hearing/vad.py), the array
(hearing/steering.py), and whether a keyword was said, alone or inside a sentence, with the keyword
spotted ahead of the detector's cut (hearing/keywords.py: KeywordSpotter, keyword_in_a_sentence,
LookAhead).
"""
from __future__ import annotations

import asyncio
import time

from hearing.vad import HeardUtterance, VoiceActivity

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
