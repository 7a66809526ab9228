"""The Core Agent's small behaviours: what it listens to besides requests (agents/core_agent.py
says when each is active).

  UserChat            plain chat from the robot's owner (user-listener, busy-chat)
  MicrophoneListener  what the robot's microphone hears while the Core supervises (typed utterances)
  AudioListener       the microphone's sound while the Core supervises: voice activity -> utterances
  MicrophoneStream    the same listening as a plain loop (the Core's supervision words during a task)
  HeartbeatMonitor    the Dynamic Agent's one-way heartbeats (with `heartbeat_template()`)
  SafetyMonitor       the range sensors: an obstacle too close latches the emergency stop (paper 003)
"""
from __future__ import annotations

import asyncio
import base64
import logging
import time
from collections import deque
from typing import TYPE_CHECKING

from spade.behaviour import CyclicBehaviour, PeriodicBehaviour
from spade.message import Message
from spade.template import Template

from ontology import core as C
from ontology.robot import CaptureAudio
from robots.errors import UnsupportedOperation
from robots.receptors import VoiceActivity
from robots.sound import decode_wav

from .messages import AclInfo, bare

if TYPE_CHECKING:
    from .core_agent import CoreAgent


class UserChat(CyclicBehaviour):
    """Takes plain chat (no ACL performative) from the robot's owner."""

    def __init__(self, owner: str, on_text):
        super().__init__()
        self.owner, self.on_text = owner, on_text

    def match(self, message: Message) -> bool:
        return not AclInfo.of(message).is_acl and bare(message.sender) == self.owner

    async def run(self) -> None:
        msg = await self.receive(timeout=0.5)
        if msg is not None and (msg.body or "").strip():
            await self.on_text(msg.body.strip())


class MicrophoneListener(CyclicBehaviour):
    """The robot's microphone: each utterance heard while the Core supervises is a command."""

    def __init__(self, microphone, on_text):
        super().__init__()
        self.microphone, self.on_text = microphone, on_text

    async def run(self) -> None:
        text = await self.microphone.listen(timeout=0.5)
        if self.is_killed():  # deactivated while listening: the utterance belongs to the RApp now
            if text:
                self.microphone.hear(text)
            return
        if text and text.strip():
            await self.on_text(text.strip())


class MicrophoneStream:
    """The microphone's sound through the robot interface (capture_audio), voice activity detection,
    each finished utterance to `on_utterance`. While `muted()` (the robot itself speaks) the sound is
    dropped: the Core never hears itself. Capturing takes nothing from anyone: a RApp capturing the
    same microphone meanwhile gets the same samples.

    A capture records from "now", and the world moves on between two requests (more so while a RApp's
    own calls drive it), so pieces of 2 x `chunk_s` are kept in flight two at a time, staggered by
    `chunk_s`, and stitched by their time stamps: each new piece adds the sound after the last one's
    end, and none falls between two unless the next request comes more than `chunk_s` late. Paced at
    real time at most (a world running as fast as possible is not driven faster by listening).

    A listener that drives the world (s3) hears the world at that pace: time others make pass faster
    than real time (another robot's sentence in an unpaced world) goes by it, as it always did. Only an
    observing stream (beside a task, `observe`) catches up after a gap, with more observing pieces taken
    at once for a while: they record the time the task makes pass and drive nothing. (Catching up in
    s3 fed back: two Cores on one unpaced world took each other's pieces for gaps and drove it at ~100
    simulated s per s; and each heard the other's sentences and answered them, "Sorry, I did not
    understand", back and forth.)

    `sentences()` counts the sentences the robot has begun to say: a piece in flight while it changed
    is dropped like a muted one, even when the sentence began and ended (an unpaced world plays it at
    once) between two looks at `muted()`. `spoke_during(t0, t1)`, where the robot can tell, is the
    simulation time its loudspeaker's sound in that stretch ends (None: silent): only a piece's sound
    after it is heard, whenever the piece is looked at (the detector had otherwise learnt a RApp's loud
    sentence as the room's noise, and then missed the owner's "stop"); the owner's words right after
    the robot's are kept."""

    CHUNK_S = 0.1  # new sound per piece (its latency)
    UNPACED_PIECES = 50  # after a gap: pieces taken at once, not paced
    MAX_HOLE_S = 0.05  # an observing stream bridges a hole this short (a driving stream none)

    def __init__(self, robot, on_utterance, muted, alive=lambda: True, chunk_s: float = CHUNK_S,
                 vad: VoiceActivity | None = None, observe: bool = False, sentences=lambda: 0,
                 spoke_during=None):
        self.robot, self.on_utterance, self.muted, self.alive = robot, on_utterance, muted, alive
        self.sentences, self.spoke_during = sentences, spoke_during
        # observe: record only what others make pass (beside a task: listening must not drive the world;
        # a fast world otherwise ran thousands of simulated seconds while the task waited on the Platform)
        self.observe = observe
        self.chunk_s = chunk_s
        # a listener's detector may outlive it: what it learnt of the room's noise stays useful
        self.vad = vad if vad is not None else VoiceActivity(max_seconds=5.0)  # 5 s: one speech_recognition request
        self.vad.reset()  # but no half utterance from before
        self._next: float | None = None  # simulation time the sound so far ends
        self._inflight: deque[asyncio.Future] = deque()
        self._muted_at_request: set[asyncio.Future] = set()  # requested while the robot spoke: its sound is dropped
        self._said_at_request: dict[asyncio.Future, int] = {}  # sentences() when each piece was requested
        self._unpaced = 0

    def _capture(self, seconds: float) -> None:
        piece = asyncio.ensure_future(self.robot.handle(CaptureAudio(seconds=seconds, observe=self.observe)))
        self._inflight.append(piece)
        if self.muted():
            self._muted_at_request.add(piece)
        self._said_at_request[piece] = self.sentences()

    async def step(self) -> bool:
        """Take the next piece of sound; False when the robot has no audio input."""
        start = time.monotonic()
        was_muted = self.muted()
        if not self._inflight:  # the short one ends half-way through the long one
            self._capture(2 * self.chunk_s)
            self._capture(self.chunk_s)
        done, _ = await asyncio.wait(self._inflight, return_when=asyncio.FIRST_COMPLETED)
        piece = next(f for f in self._inflight if f in done)
        self._inflight.remove(piece)
        if piece in self._muted_at_request:  # it began while the robot spoke: its tail is the robot's voice
            self._muted_at_request.discard(piece)
            was_muted = True
        if self._said_at_request.pop(piece, None) != self.sentences():  # the robot began a sentence meanwhile
            was_muted = True
        try:
            audio = piece.result()
            pcm, _ = decode_wav(base64.b64decode(audio.data_b64))
        except UnsupportedOperation:
            self.close()
            return False
        except Exception as e:  # noqa: BLE001 - a world being closed, a driver hiccup: listen again soon
            logging.getLogger("rapp.core").debug("audio capture failed: %s", e)
            self.close()
            await asyncio.sleep(1.0)
            return True
        robot_until = self.spoke_during(audio.stamp, audio.stamp + audio.seconds) if self.spoke_during else None
        if self._unpaced > 0:
            self._capture(2 * self.chunk_s)  # at once, before this piece is looked at (observing: drives nothing)
        pcm, gap = self._new_sound(audio, pcm)
        if not self.alive():
            return True  # stopped meanwhile: the utterance is no longer ours to act on
        if gap:  # sound went by unheard: an utterance with a hole in it is none (the recognisers mishear it)
            self.vad.reset()
        if robot_until is not None:  # the robot's own voice is in this piece: only the sound after it counts
            self.vad.reset()
            new_from = audio.stamp + audio.seconds - pcm.size / audio.sample_rate
            pcm = pcm[max(0, round((robot_until - new_from) * audio.sample_rate)):]
        if was_muted or self.muted():
            self.vad.reset()
        elif pcm.size:
            for utterance in self.vad.feed(pcm):
                await self.on_utterance(utterance)
        if len(self._inflight) < 2:
            await asyncio.sleep(max(0.0, start + self.chunk_s - time.monotonic()))
            self._capture(2 * self.chunk_s)
        return True

    def _new_sound(self, audio, pcm):
        """(the part of a piece after the sound so far, whether sound went by unheard before it). A gap
        makes an observing stream catch up a while."""
        end = audio.stamp + audio.seconds
        if self._next is None or audio.stamp > self._next + 0.002:
            # an observing stream's pieces meet end to end, a few ms apart under load: only a hole of about
            # a phone's length is a gap there; a driving stream's pieces overlap, and any hole is one
            gap = self._next is not None and (not self.observe or audio.stamp > self._next + self.MAX_HOLE_S)
            if self._next is not None and self.observe:
                self._unpaced = self.UNPACED_PIECES
            self._next = end
            return pcm, gap
        self._unpaced = max(0, self._unpaced - 1)
        skip = max(0, round((self._next - audio.stamp) * audio.sample_rate))
        self._next = max(self._next, end)
        return pcm[skip:], False

    def close(self) -> None:
        for f in self._inflight:
            f.cancel()
        self._inflight.clear()
        self._muted_at_request.clear()
        self._said_at_request.clear()
        self._next = None

    async def run_forever(self) -> None:
        """Listen until cancelled (or the robot turns out to have no audio input)."""
        try:
            while await self.step():
                pass
        finally:
            self.close()


class AudioListener(CyclicBehaviour):
    """Listens continuously while the Core supervises (fig. 5, s3): a MicrophoneStream as a behaviour."""

    CHUNK_S = MicrophoneStream.CHUNK_S

    def __init__(self, robot, on_utterance, muted, vad: VoiceActivity | None = None, sentences=lambda: 0,
                 spoke_during=None):
        super().__init__()
        self.stream = MicrophoneStream(robot, on_utterance, muted, alive=lambda: not self.is_killed(), vad=vad,
                                       sentences=sentences, spoke_during=spoke_during)
        self.vad = self.stream.vad

    async def run(self) -> None:
        if not await self.stream.step():
            self.kill()

    async def on_end(self) -> None:
        self.stream.close()


class HeartbeatMonitor(CyclicBehaviour):
    """Takes the Dynamic Agent's one-way heartbeats (inform, ontology core)."""

    def __init__(self, on_beat):
        super().__init__()
        self.on_beat = on_beat

    async def run(self) -> None:
        msg = await self.receive(timeout=0.5)
        if msg is not None:
            self.on_beat(bare(msg.sender))


def heartbeat_template() -> Template:
    return Template(metadata={"ontology": C.ONTOLOGY, "performative": "inform", "action": "heartbeat"})


class SafetyMonitor(PeriodicBehaviour):
    """Reads the range sensors; an obstacle closer than the safety distance latches the e-stop, then
    the reactive strategies (agents/core_strategies.py) decide how to hand the robot back."""

    def __init__(self, core: CoreAgent, period: float):
        super().__init__(period=period)
        self.core = core

    async def run(self) -> None:
        core = self.core
        if core.estop_reason is not None or (core.locks.holder("base") is None and not core.driving):
            return  # latched already, or the base is not being driven
        if not core.robot.moving_forward():
            return  # turning on the spot or standing: a wall beside a sideways-angled sonar is no danger
        nearest = await core.nearest_obstacle()
        if nearest is not None and nearest < core.safety_distance:
            await core.emergency_stop(f"obstacle ahead within {core.safety_distance:.2f} m of the "
                                      f"range sensors' minimum", by="safety")
            core._in_background(core.react_to_obstacle())  # agents/core_strategies.py
