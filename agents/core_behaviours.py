"""The Core Agent's small behaviours: what it listens to besides requests (agents/core_agent.py
says when each is active).

  UserChat            plain chat from the robot's owner (user-listener, busy-chat)
  MicrophoneListener  what the robot's microphone hears while the Core supervises (typed utterances)
  AudioListener       the microphone's sound while the Core supervises: voice activity -> utterances
  HeartbeatMonitor    the Dynamic Agent's one-way heartbeats (with `heartbeat_template()`)
  SafetyMonitor       the range sensors: an obstacle too close latches the emergency stop (paper 003)
"""
from __future__ import annotations

import asyncio
import base64
import logging
import time
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


class AudioListener(CyclicBehaviour):
    """Listens continuously (fig. 5, s3): the microphone's sound in CHUNK_S pieces through the robot
    interface (capture_audio), voice activity detection, each finished utterance to `on_utterance`.
    Paced at real time at most (a world running as fast as possible is not driven faster by listening).
    While the robot itself speaks (`muted()`) the sound is dropped: the Core never hears itself."""

    CHUNK_S = 0.1

    def __init__(self, robot, on_utterance, muted):
        super().__init__()
        self.robot, self.on_utterance, self.muted = robot, on_utterance, muted
        self.vad = VoiceActivity(max_seconds=5.0)  # what one speech_recognition request carries

    async def run(self) -> None:
        start = time.monotonic()
        was_muted = self.muted()
        try:
            audio = await self.robot.handle(CaptureAudio(seconds=self.CHUNK_S))
            pcm, _ = decode_wav(base64.b64decode(audio.data_b64))
        except UnsupportedOperation:
            self.kill()
            return
        except Exception as e:  # noqa: BLE001 - a world being closed, a driver hiccup: listen again soon
            logging.getLogger("rapp.core").debug("audio capture failed: %s", e)
            await asyncio.sleep(1.0)
            return
        if self.is_killed():
            return  # deactivated meanwhile: the microphone is the RApp's now
        if was_muted or self.muted():
            self.vad.reset()
        else:
            for utterance in self.vad.feed(pcm):
                await self.on_utterance(utterance)
        await asyncio.sleep(max(0.0, start + self.CHUNK_S - time.monotonic()))


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
