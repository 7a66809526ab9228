"""The simulated robot's loudspeaker, playing into the house's sound (robots/sound.py); the NAO's
speech is synthesised by hearing/tts.py (robots/api.py `say`). Imports nothing of the robot's body:
the robot is whatever has a `name`, a `pose`, a `spec`, a `world` and a `loudspeaker`."""
from __future__ import annotations

import math

import numpy as np

from .errors import UnsupportedOperation


class Loudspeaker:
    """The robot's loudspeaker: what was said (text, with simulation time) and the audio it played,
    which also sounds in the house (a source at the robot's head, heard by every microphone)."""

    SECONDS_PER_WORD = 0.35
    FULL_SCALE_DB_SPL = 88.0  # at 1 m, a full-scale sine: eSpeak's speech comes out near 66 dB
    KEEP = 32  # recent clips kept for inspection

    def __init__(self, robot):
        self.robot = robot
        self.spoken: list[tuple[float, str]] = []
        self.played: list[tuple[float, str | None, np.ndarray]] = []

    def duration(self, text: str) -> float:
        """An estimate without audio (a robot whose speech is not synthesised)."""
        return 0.3 + self.SECONDS_PER_WORD * len(text.split())

    def say(self, text: str, t: float) -> None:
        self.spoken.append((t, text))

    def position(self) -> tuple[float, float, float]:
        x, y, _ = self.robot.pose
        return x, y, self.robot.spec.collision_height + 0.05

    def play(self, pcm: np.ndarray, t: float, text: str | None = None) -> float:
        """Play 16 kHz int16 audio from simulation time `t` into the house; its duration in seconds."""
        from .sound import SAMPLE_RATE, house_sound
        if text is not None:
            self.say(text, t)
        self.played = (self.played + [(t, text, pcm)])[-self.KEEP:]
        house = house_sound(self.robot.world)
        house.prune(t - 60.0)
        house.play(f"loudspeaker:{self.robot.name}:{len(self.spoken)}:{t:.3f}", self.position(), pcm, t,
                   level_db=None, full_scale_db=self.FULL_SCALE_DB_SPL)
        return len(pcm) / SAMPLE_RATE

    def now(self) -> float:
        """Simulation time: the clock of the microphones' sound (robots.interface.LoudspeakerTiming)."""
        return self.robot.world.time

    def sounding_until(self, t0: float, t1: float, tail: float = 0.0) -> float | None:
        """When the sound it played within [t0, t1] of simulation time ends (+ `tail`, e.g. its way to a
        microphone), or None: silent then."""
        from .sound import SAMPLE_RATE
        recent = [(start, start + len(pcm) / SAMPLE_RATE + tail) for start, _, pcm in self.played[-8:]]
        ends = [end for start, end in recent if start <= t1 and end > t0]
        return max(ends) if ends else None

    def silence(self, t: float) -> None:
        """Cut off what is still playing at simulation time `t` (the emergency stop)."""
        from .sound import house_sound
        house = house_sound(self.robot.world)
        prefix = f"loudspeaker:{self.robot.name}:"
        for source_id, source in list(house.sources.items()):
            if source_id.startswith(prefix) and (source.end() or math.inf) > t:
                house.remove(source_id)


def check_speech(robot) -> Loudspeaker:
    if robot.loudspeaker is None:
        raise UnsupportedOperation(f"{robot.spec.kind} has no speech synthesis (no loudspeaker); say is not available")
    return robot.loudspeaker

