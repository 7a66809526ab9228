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
import dataclasses
import logging
import time

from spade.behaviour import CyclicBehaviour, PeriodicBehaviour
from spade.message import Message
from spade.template import Template

from ontology import core as C
from ontology.robot import CaptureAudio
from hearing.steering import Steering
from hearing.vad import HeardUtterance, VoiceActivity
from hearing.wav import decode_wav
from robots.errors import UnsupportedOperation

from .core_parts import SafetyLatch
from .messages import AclInfo, bare


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
    each finished utterance to `on_utterance`. The Core never hears itself: its own voice is cut out
    (below). Capturing takes nothing from anyone: a RApp capturing the same microphone meanwhile gets
    the same samples.

    One piece at a time, each `since` the end of the one before (CaptureAudio.since): the robot's audio
    device buffers the sound, so a listener that falls behind (a slow CPU, a RApp's own calls driving
    the world meanwhile) hears every sample, only later; nothing falls between two pieces. (Pieces
    recorded "from now" left holes whenever a request came late, ~0.1 s each under CI's load, and the
    recognisers misheard the utterance around a hole: "let's play a game" came out "read my e-mail".)
    A piece is at least `chunk_s` of new sound (its latency). Paced at real time at most (a world
    running as fast as possible is not driven faster by listening); a listener that drives the world
    (s3) drives it no further than its own next piece, one that observes (beside a task, `observe`)
    drives nothing.

    The robot's own voice: where the robot can tell, `spoke_during(t0, t1)` is the simulation time its
    loudspeaker's sound within that stretch ends (None: silent), and only a piece's sound after it is
    heard; the owner's words right after the robot's are kept (the detector had otherwise learnt a
    RApp's loud sentence as the room's noise, and then missed the owner's "stop"). Where it cannot
    (`spoke_during` None), a piece is dropped when the robot may have spoken while its sound was made:
    a piece's sound is made after the previous piece's request (its end was the world's time then, or
    later), so `muted()` (the robot speaks) at the previous piece's request or reply or at this one's,
    or `sentences()` (sentences the robot has begun) changed since the previous piece's request (an
    unpaced world plays a sentence at once, between two looks at `muted()`), drops it."""

    CHUNK_S = 0.1  # new sound per piece (its latency)

    def __init__(self, robot, on_utterance, muted, alive=lambda: True, chunk_s: float = CHUNK_S,
                 vad: VoiceActivity | None = None, observe: bool = False, sentences=lambda: 0,
                 spoke_during=None, array: bool = True, steering: Steering | None = None, on_ending=None):
        self.robot, self.on_utterance, self.muted, self.alive = robot, on_utterance, muted, alive
        # on_ending: told the utterance the detector will cut unless speech comes again, 0.1 s before
        # the cut (VoiceActivity.ending), steered as the cut will be: a listener may start on it early
        self.on_ending = on_ending
        self._early: tuple[tuple[int, int], asyncio.Future] | None = None  # ((end, samples), its steering)
        self.sentences, self.spoke_during = sentences, spoke_during
        # observe: record only what others make pass (beside a task: listening must not drive the world;
        # a fast world otherwise ran thousands of simulated seconds while the task waited on the Platform)
        self.observe = observe
        self.chunk_s = chunk_s
        # every microphone of the robot's array, the detector on the first: an utterance it cuts is
        # heard again with all of them, steered to where it came from (hearing/steering.py Steering,
        # which may outlive the listener, as its detector does)
        self.array, self.steering = array, steering if steering is not None else Steering()
        # a listener's detector may outlive it: what it learnt of the room's noise stays useful
        self.vad = vad if vad is not None else VoiceActivity(max_seconds=5.0)  # 5 s: one speech_recognition request
        self.vad.reset()  # but no half utterance from before
        self._next: float | None = None  # simulation time the sound so far ends
        self._piece: asyncio.Future | None = None
        # without spoke_during: (sentences(), muted at request or reply) of the previous piece
        self._before: tuple[int, bool] | None = None

    async def step(self) -> bool:
        """Take the next piece of sound; False when the robot has no audio input."""
        start = time.monotonic()
        said, was_muted = self.sentences(), self.muted()
        said_before, muted_before = self._before if self._before is not None else (said, was_muted)
        self._piece = asyncio.ensure_future(self.robot.handle(
            CaptureAudio(seconds=self.chunk_s, observe=self.observe, since=self._next, array=self.array)))
        try:
            audio = await self._piece
            pcm, _ = decode_wav(base64.b64decode(audio.data_b64), channels=audio.channels)
        except UnsupportedOperation:
            self.close()
            return False
        except Exception as e:  # noqa: BLE001 - a world being closed, a driver hiccup: listen again soon
            logging.getLogger("rapp.core").debug("audio capture failed: %s", e)
            self.close()
            await asyncio.sleep(1.0)
            return True
        finally:
            self._piece = None
        if not self.alive():
            return True  # stopped meanwhile: the utterance is no longer ours to act on
        rate, four = audio.sample_rate, None
        if audio.channels > 1:
            four, pcm = pcm, pcm[0]
        if self._next is not None and audio.stamp > self._next + 0.5 / rate:
            self.vad.reset()  # older than the device keeps: sound went by unheard, an utterance with a hole is none
        self._next = audio.stamp + len(pcm) / rate
        if self.spoke_during is not None:
            robot_until = self.spoke_during(audio.stamp, self._next)
            if robot_until is not None:  # the robot's own voice is in this piece: only the sound after it counts
                self.vad.reset()
                pcm = pcm[max(0, round((robot_until - audio.stamp) * rate)):]
        else:
            muted_now = self.muted()
            self._before = said, was_muted or muted_now
            if muted_before or was_muted or muted_now or self.sentences() != said_before:
                self.vad.reset()
                pcm = pcm[:0]
        if pcm.size and four is not None:  # the array's filter and the detector: a few ms of CPU
            if self._early is not None and not self._early[1].done():
                await asyncio.wait({self._early[1]})  # Steering is not thread-safe: its steering ahead ends first
            heard = await asyncio.get_running_loop().run_in_executor(
                None, self.steering.listen, self.vad, four[:, four.shape[1] - len(pcm):], audio.microphones)
            for utterance, end in heard:
                await self.on_utterance(await self._steered(utterance, end))
            if self.on_ending is not None:
                self._look_ahead(self.steering.ending(self.vad))
        elif pcm.size:
            for utterance in self.vad.feed(pcm):
                await self.on_utterance(utterance)
            if self.on_ending is not None:
                ending = self.vad.ending()
                self._look_ahead(None if ending is None else (ending, None))
        await asyncio.sleep(max(0.0, start + self.chunk_s - time.monotonic()))
        return True

    def _look_ahead(self, ending: tuple[HeardUtterance, int | None] | None) -> None:
        """Steer the utterance the detector is about to cut and tell on_ending, once per utterance."""
        if ending is None:
            return
        utterance, end = ending
        key = (utterance.end_sample if end is None else end, len(utterance.pcm))
        if self._early is not None and self._early[0] == key:
            return
        if self._early is not None:
            self._early[1].cancel()  # the owner went on: that end was not one

        async def early() -> HeardUtterance:
            steered = utterance if end is None else await self._steer(utterance, end)
            try:
                await self.on_ending(steered)
            except Exception as e:  # noqa: BLE001 - a look ahead that fails costs only its time
                logging.getLogger("rapp.core").warning("looking ahead at an utterance failed: %r", e)
            return steered
        self._early = (key, asyncio.ensure_future(early()))

    async def _steered(self, utterance: HeardUtterance, end: int) -> HeardUtterance:
        """The utterance as the whole array hears it (where the array still keeps its sound)."""
        if utterance.too_long:
            return utterance
        early, self._early = self._early, None
        if early is not None and early[0] == (end, len(utterance.pcm)):
            return await early[1]  # the cut is the utterance steered ahead of it (VoiceActivity.ending)
        return await self._steer(utterance, end)

    async def _steer(self, utterance: HeardUtterance, end: int) -> HeardUtterance:
        """Steering.steered on the utterance's samples (the one microphone's where that cannot be)."""
        got = await asyncio.get_running_loop().run_in_executor(None, self.steering.steered, len(utterance.pcm), end)
        if got is None:
            return utterance
        return dataclasses.replace(utterance, pcm=got[0], bearing=got[1])

    def close(self) -> None:
        if self._piece is not None:
            self._piece.cancel()
        if self._early is not None:
            self._early[1].cancel()
            self._early = None
        self._next, self._before = None, None

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
                 spoke_during=None, steering: Steering | None = None, on_ending=None):
        super().__init__()
        self.stream = MicrophoneStream(robot, on_utterance, muted, alive=lambda: not self.is_killed(), vad=vad,
                                       sentences=sentences, spoke_during=spoke_during, steering=steering,
                                       on_ending=on_ending)
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

    def __init__(self, latch: SafetyLatch, period: float):
        super().__init__(period=period)
        self.latch = latch

    async def run(self) -> None:
        latch = self.latch
        if latch.estop_reason is not None or (latch.locks.holder("base") is None and not latch.driving):
            return  # latched already, or the base is not being driven
        if not latch.robot.moving_forward():
            return  # turning on the spot or standing: a wall beside a sideways-angled sonar is no danger
        nearest = await latch.nearest_obstacle()
        distance = latch.safety_distance or 0.0
        if nearest is not None and nearest < distance:
            await latch.safety_stop(f"obstacle ahead within {distance:.2f} m of the range sensors' minimum")
