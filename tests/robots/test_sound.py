"""Sound in the house: propagation (distance, walls, doors), determinism, the NAO's synthesised speech,
and the robot API's audio actions (capture, play, level, word spotting on real audio)."""
import base64
import math

import numpy as np
import pytest

from ontology.errors import ErrorCode
from ontology.robot import AUDIO_BUFFER_S, MAX_AUDIO_SECONDS, CaptureAudio, MicrophoneEnergy, PlayAudio, Say, WordSpotting
from hearing import tts
from hearing.errors import BadAudio
from hearing.wav import decode_wav, encode_wav, level_dbfs
from robots import InvalidArgument, UnsupportedOperation
from robots.floorplan import load_plan
from robots.sound import WALL_LOSS_DB, DOOR_LOSS_DB, HouseSound, NoiseSource, house_sound
from robots.reverb import critical_distance
from robots.world import HOUSES

from .conftest import api_at

SPEECH = tts.synthesize("check the hazards")


def _house(doors=0, seed=1):
    return HouseSound(load_plan(HOUSES / "small.yaml", seed=seed, overrides={"doors": {"d1": doors}}))


def _rms_db(house, mic, t0=0.0, seconds=1.0):
    return level_dbfs(house.receive(mic, t0, seconds, noise_db=-200))[0]


def test_level_falls_6_db_per_doubling_of_distance():
    house = _house()
    house.add(NoiseSource("radio", (0.5, 2.0, 1.0), kind="radio", level_db=70, seed=1))
    levels = [_rms_db(house, (0.5 + d, 2.0, 1.0)) for d in (0.5, 1.0, 2.0)]
    assert levels[0] - levels[1] == pytest.approx(6.02, abs=0.3)
    assert levels[1] - levels[2] == pytest.approx(6.02, abs=0.3)


def test_a_wall_and_a_closed_door_attenuate_an_open_doorway_does_not():
    src, through_wall, free = (4.5, 3.0, 1.0), (2.5, 3.0, 1.0), (4.5, 1.0, 1.0)  # 2 m each
    closed, open_ = _house(doors=0), _house(doors=90)
    for h in (closed, open_):
        h.add(NoiseSource("tv", src, kind="white", level_db=70, seed=1))
    assert _rms_db(closed, free) - _rms_db(closed, through_wall) == pytest.approx(WALL_LOSS_DB, abs=0.5)
    # the door d1 fills the gap from (3.5, 1.0) to (3.5, 1.9): a line through it
    a, b = (4.5, 1.45, 1.0), (2.5, 1.45, 1.0)
    for h in (closed, open_):
        h.sources.clear()
        h.add(NoiseSource("tv", a, kind="white", level_db=70, seed=1))
    assert closed.walls_between(a, b) == (0, 1) and open_.walls_between(a, b) == (0, 0)
    assert _rms_db(open_, b) - _rms_db(closed, b) == pytest.approx(DOOR_LOSS_DB, abs=0.5)


def test_recordings_are_deterministic_per_seed_and_independent_of_chunking():
    def record(seed, chunks):
        h = _house(seed=seed)
        h.add(NoiseSource("tv", (1.0, 1.0, 0.8), kind="tv", level_db=65, seed=h.seed))
        h.play("owner", (2.0, 2.0, 1.6), SPEECH, at=0.3)
        step = 3.0 / chunks
        return np.concatenate([h.receive((2.5, 2.5, 0.5), k * step, step, mic="nao") for k in range(chunks)])

    a, b, c = record(1, 1), record(1, 6), record(2, 1)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert level_dbfs(a)[0] > -60  # something was heard


def test_speech_arrives_delayed_by_the_distance():
    h = _house()
    click = np.zeros(1600, np.int16)
    click[0] = 20000
    h.play("click", (0.5, 2.0, 1.0), click, at=0.0, level_db=None)
    got = h.receive((3.43, 2.0, 1.0), 0.0, 0.05, noise_db=-200)  # 2.93 m: 8.54 ms
    assert int(np.argmax(np.abs(got))) == round(2.93 / 343 * 16000)


def _reverberant(rt60=0.5, seed=1):
    return HouseSound(load_plan(HOUSES / "small.yaml", seed=seed, overrides={"acoustics": {"rt60_s": rt60}}))


def test_reverberation_is_as_loud_as_sabine_says_and_dies_away_in_rt60():
    dry, wet = _house(), _reverberant(0.5)
    living = next(r.rect for r in wet.plan.rooms if r.name == "living")
    r_c = critical_distance((living[2] - living[0]) * (living[3] - living[1]) * wet.plan.wall_height, 0.5)
    for h in (dry, wet):
        h.add(NoiseSource("radio", (0.5, 2.0, 1.0), kind="white", level_db=70, seed=1))
    # at 2 m the diffuse field is (2 / r_c)^2 times the direct sound (~13 dB added)
    added = _rms_db(wet, (2.5, 2.0, 1.0), 1.0) - _rms_db(dry, (2.5, 2.0, 1.0), 1.0)
    assert added == pytest.approx(10 * math.log10(1 + (2.0 / r_c) ** 2), abs=1.0)
    # a click's tail: 60 dB in RT60, so 30 dB between 50-100 ms and 300-350 ms after it
    click = np.zeros(160, np.int16)
    click[0] = 30000
    wet.sources.clear()
    wet.play("click", (0.5, 2.0, 1.0), click, at=0.0, level_db=None)
    got = wet.receive((2.5, 2.0, 1.0), 0.0, 0.5, noise_db=-200).astype(np.float64)
    energy = [10 * math.log10(np.mean(got[round(a * 16000):round(b * 16000)] ** 2)) for a, b in ((0.05, 0.1), (0.3, 0.35))]
    assert energy[0] - energy[1] == pytest.approx(30.0, abs=4.0)


def test_a_reverberant_recording_rings_on_and_does_not_depend_on_chunking():
    def record(rt60, chunks):
        h = _reverberant(rt60)
        h.play("owner", (2.0, 2.0, 1.6), SPEECH, at=0.3)
        step = 3.5 / chunks
        return np.concatenate([h.receive((2.5, 2.5, 0.5), k * step, step, mic="nao", noise_db=-200)
                               for k in range(chunks)])

    whole, cut = record(0.5, 1), record(0.5, 7)
    assert np.abs(whole.astype(int) - cut).max() <= 1  # float rounding of the convolution, no more
    end = round(0.3 * 16000) + len(SPEECH)
    after = slice(end + 1600, end + 4800)  # 0.1-0.3 s after the owner stopped
    assert level_dbfs(whole[after])[0] > -85 and level_dbfs(record(0.0, 1)[after])[0] < -110


def test_an_echo_is_forgotten_with_its_source():
    # every utterance is a source of its own: their echoes must not pile up over a long run
    h = _reverberant(0.3)
    h.play("owner-1", (2.0, 2.0, 1.6), SPEECH, at=0.0)
    h.add(NoiseSource("tv", (1.0, 1.0, 0.8), kind="tv", level_db=50, seed=1))
    h.receive((2.5, 2.5, 0.5), 0.0, 0.5)
    assert {source for source, _ in h._tails} == {"owner-1", "tv"}
    h.prune(before=60.0)
    h.remove("tv")
    assert h._tails == {}


@pytest.mark.parametrize("bad", [-0.1, 5.0, "loud", None])
def test_a_bad_reverberation_time_is_a_clear_error(bad):
    with pytest.raises(ValueError, match="rt60_s"):
        _reverberant(bad)


async def test_the_nao_speaks_into_the_house_and_the_elektron_hears_it(small):
    nao = api_at(small, "nao", (1.0, 2.4, 0))
    el = api_at(small, "elektron", (2.0, 2.4, 180))
    quiet = await el.microphone_energy(MicrophoneEnergy(seconds=0.5))
    t0 = small.time
    await nao.say(Say(text="check the hazards", voice="en-us+f3", speed=140))
    t_said, text, pcm = nao.robot.loudspeaker.played[-1]
    assert text == "check the hazards" and small.time - t0 == pytest.approx(len(pcm) / 16000, abs=0.05)
    heard = el.audio_in.record(el.audio_in.position(), t_said, len(pcm) / 16000)
    assert level_dbfs(heard)[0] > quiet.rms_dbfs + 25  # speech at 1 m over the microphone's own noise
    with pytest.raises(UnsupportedOperation, match="speech"):
        await el.say(Say(text="hello"))
    with pytest.raises(UnsupportedOperation):
        await el.play_audio(PlayAudio(data_b64=base64.b64encode(encode_wav(SPEECH)).decode()))


async def test_capture_and_play_audio_through_the_api(small):
    nao = api_at(small, "nao", (1.0, 2.4, 0))
    el = api_at(small, "elektron", (1.8, 2.4, 180))
    rec = await el.capture_audio(CaptureAudio(seconds=0.5, sample_rate=8000))
    pcm, rate = decode_wav(base64.b64decode(rec.data_b64), rates=(8000,))
    assert rate == 8000 and len(pcm) == 4000 and rec.seconds == 0.5
    t0 = small.time
    await nao.play_audio(PlayAudio(data_b64=base64.b64encode(encode_wav(SPEECH)).decode()))
    assert small.time - t0 == pytest.approx(len(SPEECH) / 16000, abs=0.05)
    with pytest.raises(BadAudio) as e:
        await nao.play_audio(PlayAudio(data_b64=base64.b64encode(b"not a wav").decode()))
    assert e.value.code == ErrorCode.MALFORMED


async def test_a_late_capture_since_the_last_one_loses_no_sound(small):
    nao = api_at(small, "nao", (1.0, 2.4, 0))
    pos = nao.audio_in.position()
    house_sound(small).play("owner", (2.0, 2.4, 1.6), SPEECH, at=small.time + 0.05)
    first = await nao.capture_audio(CaptureAudio(seconds=0.1))
    await small.sleep(1.01)  # the listener falls behind (a slow CPU): the world goes on without it (61 steps)
    t_now = small.time
    late = await nao.capture_audio(CaptureAudio(seconds=0.1, since=first.stamp + first.seconds))
    assert small.time == t_now  # what has passed comes at once
    assert late.stamp == pytest.approx(first.stamp + first.seconds, abs=1e-9)
    assert late.seconds == pytest.approx(1.0167, abs=0.001)
    pcm = np.concatenate([decode_wav(base64.b64decode(a.data_b64))[0] for a in (first, late)])
    assert np.array_equal(pcm, nao.audio_in.record(pos, first.stamp, len(pcm) / 16000))  # one recording, no hole
    # up to date (the world's time is between two samples): it waits for `seconds` of new sound
    since = late.stamp + late.seconds
    assert since <= small.time
    nxt = await nao.capture_audio(CaptureAudio(seconds=0.1, since=since))
    assert nxt.stamp == pytest.approx(since) and nxt.seconds == pytest.approx(0.1, abs=0.02) and small.time >= since + 0.1
    quiet = decode_wav(base64.b64decode(nxt.data_b64))[0]
    assert level_dbfs(pcm)[0] > level_dbfs(quiet)[0] + 10  # the owner's sentence is in what came late
    # a lag longer than one message holds comes in several; beyond the device's buffer the sound is lost
    await small.sleep(AUDIO_BUFFER_S + 2.0)
    old = await nao.capture_audio(CaptureAudio(seconds=0.1, since=since))
    assert old.stamp == pytest.approx(small.time - AUDIO_BUFFER_S) and old.seconds == pytest.approx(MAX_AUDIO_SECONDS)
    with pytest.raises(InvalidArgument, match="later than the simulation time"):
        await nao.capture_audio(CaptureAudio(seconds=0.1, since=small.time + 1.0))


async def test_a_tv_raises_the_microphone_level(small):
    el = api_at(small, "elektron", (2.0, 2.4, 180))
    before = await el.microphone_energy(MicrophoneEnergy(seconds=0.5))
    house_sound(small).add(NoiseSource("tv", (0.5, 3.5, 0.8), kind="tv", level_db=65, seed=1, start=small.time))
    after = await el.microphone_energy(MicrophoneEnergy(seconds=0.5))
    assert after.rms_dbfs > before.rms_dbfs + 15


@pytest.mark.parametrize("said,expected", [("hazards", "hazards"), ("banana", None)])
async def test_word_spotting_on_real_audio(small, said, expected):
    nao = api_at(small, "nao", (1.0, 2.4, 0))
    owner = (1.0 + math.cos(0.5), 2.4 + math.sin(0.5), 1.6)  # 1 m away
    house_sound(small).play("owner", owner, tts.synthesize(said, "en-us+m3"), at=small.time + 0.5)
    got = await nao.word_spotting(WordSpotting(words=["weather", "hazards", "stop"], timeout=2.5))
    assert got.word == expected
    if expected:
        assert got.text == expected
