"""The simulated robot's microphones: what its owner types to it (Microphone, utterances as text)
and what it hears of the house (AudioInput: robots/sound.py rendered at its head, one channel or the
whole array), and the robot API's word spotting in that sound (spot_in_audio, hearing/keywords.py
WordSpotter deciding). Imports nothing of the robot's body: the robot is whatever has a `name`, a
`pose` and a `spec` (collision_height, microphones)."""
from __future__ import annotations

import asyncio
import re
import threading
from collections import deque
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from hearing.keywords import WordSpotter
from hearing.vad import speech_segments

from .mic_array import heads_mics

if TYPE_CHECKING:
    from .sound import HouseSound


class Microphone:
    """Hears text: ``hear(text)`` is what a user or scenario says (thread-safe);
    ``spot(words, timeout)`` waits (wall clock) for the first utterance containing one of the words;
    ``listen(timeout)`` returns the next utterance, whatever it is."""

    def __init__(self):
        self._heard: deque[str] = deque()
        self._lock = threading.Lock()
        self._waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = []
        self.log: list[str] = []

    def hear(self, text: str) -> None:
        with self._lock:
            self._heard.append(text)
            self.log.append(text)
            waiters = list(self._waiters)
        for loop, ev in waiters:
            try:
                loop.call_soon_threadsafe(ev.set)
            except RuntimeError:  # loop closed
                pass

    async def listen(self, timeout: float) -> str | None:
        """The next utterance, whatever it says (the Core's command listening), or None."""
        loop = asyncio.get_running_loop()
        ev = asyncio.Event()
        entry = (loop, ev)
        with self._lock:
            if self._heard:
                return self._heard.popleft()
            self._waiters.append(entry)
        try:
            try:
                await asyncio.wait_for(ev.wait(), timeout)
            except asyncio.TimeoutError:
                pass
            with self._lock:
                return self._heard.popleft() if self._heard else None
        finally:
            with self._lock:
                self._waiters.remove(entry)

    def clear(self) -> None:
        with self._lock:
            self._heard.clear()

    @staticmethod
    def match(words: list[str], text: str) -> str | None:
        low = " " + re.sub(r"[^\w\s]", " ", text.lower()) + " "
        low = re.sub(r"\s+", " ", low)
        for w in words:
            if f" {w.lower().strip()} " in low:
                return w
        return None

    async def spot(self, words: list[str], timeout: float) -> tuple[str | None, str | None]:
        loop = asyncio.get_running_loop()
        ev = asyncio.Event()
        entry = (loop, ev)
        deadline = loop.time() + timeout
        with self._lock:
            self._waiters.append(entry)
        try:
            while True:
                ev.clear()
                while True:
                    with self._lock:
                        text = self._heard.popleft() if self._heard else None
                    if text is None:
                        break
                    w = self.match(words, text)
                    if w is not None:
                        return w, text
                remaining = deadline - loop.time()
                if remaining <= 0:
                    return None, None
                try:
                    await asyncio.wait_for(ev.wait(), remaining)
                except asyncio.TimeoutError:
                    pass
        finally:
            with self._lock:
                self._waiters.remove(entry)


class AudioInput:
    """The audio path of a robot's microphone (beside Microphone's typed utterances): what the house
    sounds like at the robot's head, in simulation time."""

    def __init__(self, robot, house: "HouseSound"):
        self.robot, self.house = robot, house
        self.name = robot.name

    def position(self) -> tuple[float, float, float]:
        x, y, _ = self.robot.pose
        return x, y, self.robot.spec.collision_height + 0.05  # microphones sit in the head / top plate

    def record(self, position, t0: float, seconds: float, rate: int = 16000) -> np.ndarray:
        """int16 samples heard at `position` over [t0, t0 + seconds) (CPU work: call from an executor)."""
        return self.house.receive(position, t0, seconds, mic=self.name, rate=rate)

    def microphones(self) -> tuple[tuple[float, float, float], ...]:
        """The array's microphones in the robot's frame (one at the listening point where it has none)."""
        return self.robot.spec.microphones or ((0.0, 0.0, 0.0),)

    def record_array(self, position, heading: float, t0: float, seconds: float) -> np.ndarray:
        """record() at each microphone (channels, n), the head at `position` turned `heading` (CPU work)."""
        mics = heads_mics(self.microphones(), heading) + np.asarray(position, float)[None]
        return self.house.receive_array(mics, t0, seconds, mic=self.name)


async def spot_in_audio(audio: AudioInput, world, words: list[str], timeout: float, chunk: float = 0.5
                        ) -> tuple[str | None, str | None]:
    """Listen (simulation time) for an isolated keyword: record in chunks, cut utterances at pauses,
    decode each with a grammar of the words. (word, what was heard) or (None, None) at the timeout.

    The sound is heard from the request on, every sample of it: each chunk is recorded from the end of
    the one before up to the world's time, however far the world went on meanwhile (others driving it
    while a chunk was decoded, the decoder built on a slow CPU): late, never lost."""
    loop = asyncio.get_running_loop()
    t_next = world.time
    t_end = t_next + timeout
    spotter = await loop.run_in_executor(None, partial(WordSpotter, words))
    if not spotter.knows_any:
        await world.sleep(max(0.0, t_end - world.time))  # no word the recogniser knows: the microphone only passes time
        return None, None
    buf = np.zeros(0, np.int16)
    while t_next < t_end - 1e-9:
        if world.time < min(t_next + chunk, t_end) - 1e-9:
            await world.sleep(min(t_next + chunk, t_end) - world.time)
        t0, step = t_next, min(world.time, t_end) - t_next
        t_next = t0 + step
        buf = np.concatenate([buf, await loop.run_in_executor(None, audio.record, audio.position(), t0, step)])
        segs = speech_segments(buf)
        done = [s for s in segs if s[1] < len(buf) - 0.35 * 16000] or (segs if t_next >= t_end - 1e-9 else [])
        for s, e in done:
            word, heard = await loop.run_in_executor(None, spotter.spot, buf[s:e])
            if word is not None:
                return word, heard
        if done:
            buf = buf[done[-1][1]:]
        buf = buf[-int(8 * 16000):]  # an utterance longer than 8 s is not an isolated keyword
    return None, None
