"""The Core's microphone stream (agents/core_behaviours.py, MicrophoneStream) on a slow CPU: the world goes
on between two of its pieces (others drive it while the listener waits for the CPU), and every sample
still reaches the voice detector, late: the utterance heard is one uninterrupted stretch of the house's
sound, the owner's whole sentence. With the NAO's four microphones, the utterance the detector cuts on
one of them is heard again with all four, steered to where the owner is."""
from __future__ import annotations

import math

import numpy as np
import pytest

from agents.core_behaviours import MicrophoneStream
from hearing import tts
from hearing.steering import Steering
from robots import RobotAPI, World
from robots.sound import house_sound, talker_at


def _nao_listening(world, heading: float = 0.0, **stream_options):
    """A NAO in the small house and its microphone stream: (robot API, stream, each utterance it cuts)."""
    api = RobotAPI(world.add_robot("nao", pose=(0.6, 0.6, heading)))
    heard = []

    async def on_utterance(utterance):
        heard.append(utterance)

    stream = MicrophoneStream(api, on_utterance, muted=lambda: False, spoke_during=lambda t0, t1: None,
                              **stream_options)
    return api, stream, heard


async def test_a_stream_that_falls_behind_hears_the_whole_utterance():
    world = World.from_file("small", seed=4)
    try:
        api, stream, heard = _nao_listening(world, array=False)
        t_start = world.time
        for _ in range(8):  # the detector learns the room's quiet
            await stream.step()
        pcm = tts.synthesize("check my inbox")
        t_said = world.time + 0.3
        house_sound(world).play("owner", talker_at((0.6, 0.6), 1.0, api.audio_in.position()[2]), pcm, at=t_said,
                                level_db=60)
        while not heard and world.time < t_said + len(pcm) / 16000 + 2.0:
            await world.sleep(0.37)  # others drive the world while the listener is late
            await stream.step()
        assert len(heard) == 1 and not heard[0].too_long
        got = heard[0].pcm
        house = api.audio_in.record(api.audio_in.position(), t_start, world.time - t_start)
        # the detector's 10 ms frames start at the stream's first sample: the utterance is a run of them
        starts = [o for o in range(0, len(house) - len(got) + 1, 160) if np.array_equal(house[o:o + len(got)], got)]
        assert len(starts) == 1, "the utterance is not one uninterrupted stretch of the house's sound"
        t0 = t_start + starts[0] / 16000
        assert t0 <= t_said and t0 + len(got) / 16000 >= t_said + len(pcm) / 16000 - 0.3  # the whole sentence
    finally:
        world.close()


@pytest.mark.parametrize("heading", [0.0, 2.0])
async def test_the_array_steers_to_the_owner_and_keeps_the_detectors_cut(heading):
    world = World.from_file("small", seed=4)
    try:
        api, stream, heard = _nao_listening(world, heading)
        t_start = world.time
        for _ in range(20):  # the detector learns the room's quiet; the array, its sound before the owner
            await stream.step()
        pcm = tts.synthesize("check my inbox")
        direction = (math.cos(1.0), math.sin(1.0))  # the owner 57 degrees left of the house's x axis
        house_sound(world).play("owner", talker_at((0.6, 0.6), 1.5, api.audio_in.position()[2], direction), pcm,
                                at=world.time + 0.3, level_db=60)
        while not heard and world.time < t_start + 10:
            await world.sleep(0.23)
            await stream.step()
        assert len(heard) == 1 and heard[0].bearing is not None
        error = (math.degrees(heard[0].bearing + heading - 1.0) + 180) % 360 - 180  # the robot's frame
        assert abs(error) <= 10
        # the steered utterance is the same stretch of sound as the one microphone's cut (its delays are
        # counted from the earliest microphone, a fraction of a millisecond): the mono recording of the
        # head's centre, where the detector's cut puts it, correlates best at no lag
        got = heard[0].pcm.astype(float)
        mono = api.audio_in.record(api.audio_in.position(), t_start, world.time - t_start).astype(float)
        lags = range(-40, 41)
        end = heard[0].end_sample - Steering.DELAY  # the detector hears the array's filter's output that late
        best = max(lags, key=lambda lag: float(np.dot(got, _cut(mono, end, len(got), lag))))
        assert abs(best) <= 3
        # what the array took for the room's sound has none of the owner's words in it
        room = stream.steering.noise.astype(float)
        assert 10 * math.log10(np.mean(room ** 2)) < 10 * math.log10(np.mean(got ** 2)) - 20
    finally:
        world.close()


async def test_the_utterance_about_to_be_cut_is_steered_ahead_of_the_cut():
    world = World.from_file("small", seed=4)
    try:
        ahead = []

        async def on_ending(utterance):
            ahead.append((len(heard), utterance))  # with how many utterances were cut by then

        api, stream, heard = _nao_listening(world, on_ending=on_ending)
        for _ in range(20):
            await stream.step()
        pcm = tts.synthesize("inbox")
        house_sound(world).play("owner", talker_at((0.6, 0.6), 1.5, api.audio_in.position()[2]), pcm,
                                at=world.time + 0.3, level_db=60)
        while not heard and world.time < 10:
            await stream.step()
        # told ahead of the cut (a piece ahead when the stream keeps up: robots' VoiceActivity.ending,
        # tests/test_core_hearing.py), steered: the cut is that very utterance, steered once
        assert len(heard) == 1 and [n for n, _ in ahead] == [0]
        assert heard[0] is ahead[0][1] and heard[0].bearing is not None
    finally:
        world.close()


def _cut(mono: np.ndarray, end: int, n: int, lag: int) -> np.ndarray:
    """The n samples the detector's cut took from the start of listening (ending at `end`), shifted by `lag`."""
    return mono[end + lag - n:end + lag]
