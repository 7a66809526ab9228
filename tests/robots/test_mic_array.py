"""Several microphones on the NAO's head (robots/mic_array.py, HouseSound.receive_array): each hears a
source after its own delay, the room's echo is as coherent between them as a diffuse field's, and a
beamformer (hearing/steering.py) gains on a TV what the room allows it, no more."""
import base64
import math

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.signal import coherence

from hearing import tts
from hearing.errors import BadAudio
from hearing.steering import SPEED_OF_SOUND, Steering, mvdr, nulling_taps
from hearing.vad import VoiceActivity
from hearing.wav import decode_wav, encode_wav
from ontology.robot import CaptureAudio
from robots.floorplan import load_plan
from robots.mic_array import NAO_MICS, arrival_delays, diffuse, heads_mics
from robots.sound import HouseSound, NoiseSource, house_sound, talker_at
from robots.world import HOUSES

from .conftest import api_at

HEAD = np.array([0.6, 0.6, 0.5])
TV = (3.2, 0.5, 0.8)
SPEECH = tts.synthesize("check the hazards")


def _house(rt60=0.0):
    return HouseSound(load_plan(HOUSES / "small.yaml", seed=5, overrides={"acoustics": {"rt60_s": rt60}}))


def _mics():
    return heads_mics(NAO_MICS, 0.0) + HEAD[None]


def test_each_microphone_hears_a_source_after_its_own_delay_to_a_fraction_of_a_sample():
    house, mics = _house(), _mics()
    source = (2.0, 0.9, 0.9)
    house.play("tone", source, (0.3 * 32767 * np.sin(2 * np.pi * 500 * np.arange(16000) / 16000)).astype(np.int16),
               at=0.0)
    x = house.pressure_array(mics, 0.5, 0.25)
    t = np.arange(x.shape[1]) / 16000
    phase = [np.angle(np.sum(ch * np.exp(-2j * np.pi * 500 * t))) for ch in x]
    for k in range(1, 4):
        expected = -2 * np.pi * 500 * (math.dist(mics[k], source) - math.dist(mics[0], source)) / SPEED_OF_SOUND
        assert np.angle(np.exp(1j * (phase[k] - phase[0] - expected))) == pytest.approx(0, abs=0.01)  # 3 us


def test_one_microphone_of_the_array_hears_what_the_single_microphone_hears():
    house = _house()
    house.play("owner", tuple(HEAD + (50 * SPEED_OF_SOUND / 16000, 0.0, 0.0)), SPEECH, at=0.0)  # 50 samples away
    one = house.pressure(tuple(HEAD), 0.0, 1.0)
    arrayed = house.pressure_array([HEAD], 0.0, 1.0)[0]
    assert np.abs(one - arrayed).max() < 1e-4 * np.abs(one).max()


def test_the_rooms_echo_is_coherent_between_close_microphones_as_a_diffuse_field():
    offsets = np.array([(0.0, 0.0, 0.0), (0.06, 0.0, 0.0), (0.0, 0.4, 0.0)])
    tails = np.random.default_rng(1).normal(size=(3, 160000))
    mixed = diffuse(tails, offsets)
    assert np.mean(mixed ** 2, axis=1) == pytest.approx(np.mean(tails ** 2, axis=1), rel=0.02)
    f, near = coherence(mixed[0], mixed[1], 16000, nperseg=1024)
    _, far = coherence(mixed[0], mixed[2], 16000, nperseg=1024)
    band = (f > 300) & (f < 500)
    expected = np.sinc(2 * f[band] * 0.06 / SPEED_OF_SOUND) ** 2  # magnitude-squared: 0.98-0.99
    assert np.mean(near[band]) == pytest.approx(np.mean(expected), abs=0.03)
    assert np.mean(far[band]) < 0.1  # 40 cm apart: nearly independent


def _snr_gain(rt60: float) -> float:
    """How much an MVDR steered to the owner 2 m away raises the owner's level over a TV's (dB)."""
    mics, owner = _mics(), talker_at(tuple(HEAD[:2]), 2.0, HEAD[2])
    speech, tv = _house(rt60), _house(rt60)
    speech.play("owner", owner, SPEECH, at=0.0)
    tv.add(NoiseSource("tv", TV, kind="tv", level_db=50, seed=5, start=0.0))
    said, noise = speech.pressure_array(mics, 0.0, 1.5), tv.pressure_array(mics, 0.0, 3.0)
    heard = tv.pressure_array(mics, 4.0, 1.5)
    delays = arrival_delays(mics, owner)
    db = lambda x: 10 * math.log10(np.mean(np.asarray(x, float) ** 2))  # noqa: E731
    return (db(mvdr(said, noise, delays)) - db(said[0])) - (db(mvdr(heard, noise, delays)) - db(heard[0]))


def test_a_beamformer_gains_on_a_tv_in_an_anechoic_house_far_more_than_in_a_room():
    """The point of the coherent echo: in the anechoic house the TV is a point, which four microphones
    cancel almost entirely (26 dB: a flattering result); in a 0.3 s room most of the TV comes from
    everywhere (5.7 dB; 8.1 were the microphones' echoes independent)."""
    assert _snr_gain(0.0) > 20
    assert 3 < _snr_gain(0.3) < 7.5


def test_receive_array_gives_each_microphone_noise_of_its_own():
    house = _house()
    x = house.receive_array(_mics(), 0.0, 0.5, mic="nao")
    assert x.shape == (4, 8000) and x.dtype == np.int16
    assert abs(np.corrcoef(x[0].astype(float), x[1].astype(float))[0, 1]) < 0.05
    assert np.array_equal(x, house.receive_array(_mics(), 0.0, 0.5, mic="nao"))  # deterministic


def test_a_wav_of_several_channels_round_trips_and_a_mono_reader_refuses_it():
    four = (np.arange(4 * 800).reshape(4, 800) % 1000).astype(np.int16)
    back, rate = decode_wav(encode_wav(four), channels=4)
    assert rate == 16000 and np.array_equal(back, four)
    with pytest.raises(BadAudio, match="need mono"):
        decode_wav(encode_wav(four))
    with pytest.raises(BadAudio, match="4-channel"):
        decode_wav(encode_wav(four[0]), channels=4)


async def test_capture_audio_with_array_gives_each_microphone_and_where_it_is(small):
    nao = api_at(small, "nao", (1.0, 2.4, 90))
    el = api_at(small, "elektron", (2.0, 2.4, 0))
    house_sound(small).play("owner", (1.0, 3.4, 1.2), SPEECH, at=small.time)  # 1 m to the NAO's front
    rec = await nao.capture_audio(CaptureAudio(seconds=0.5, array=True))
    four, _ = decode_wav(base64.b64decode(rec.data_b64), channels=rec.channels)
    assert rec.channels == 4 and four.shape == (4, 8000) and rec.microphones == [tuple(m) for m in NAO_MICS]
    # turned 90 degrees, the NAO's front microphones face the owner: they hear each word first
    lag = np.argmax(np.correlate(four[2].astype(float), four[0][2000:6000].astype(float), "valid")) - 2000
    assert lag > 0
    one = await el.capture_audio(CaptureAudio(seconds=0.5, array=True))  # an Elektron has one microphone
    assert one.channels == 1 and one.microphones == [(0.0, 0.0, 0.0)]
    with pytest.raises(ValidationError, match="array"):
        CaptureAudio(seconds=2.0, array=True)  # four channels of it would not fit one message


def _tv_and_owner(level_db: float, distance: float, seconds: float = 7.0, at: float = 4.0):
    """The four microphones' samples of a TV on from the start and the owner `distance` m away from `at`."""
    house = _house()
    house.add(NoiseSource("tv", TV, kind="tv", level_db=level_db, seed=5, start=0.0))
    house.play("owner", talker_at(tuple(HEAD[:2]), distance, HEAD[2]), SPEECH, at=at, level_db=60)
    return house.receive_array(_mics(), 0.0, seconds, mic="nao")


def test_the_detectors_filter_takes_a_tv_out_and_lets_the_owner_through():
    house = _house()
    house.add(NoiseSource("tv", TV, kind="tv", level_db=60, seed=5, start=0.0))
    tv = house.receive_array(_mics(), 0.0, 6.0, mic="nao").astype(np.float64)
    owner = _house()
    owner.play("owner", talker_at(tuple(HEAD[:2]), 2.0, HEAD[2]), SPEECH, at=0.0)
    said = owner.pressure_array(_mics(), 0.0, 1.5)
    taps = nulling_taps(tv[:, :3 * 16000])
    through = lambda x: sum(np.convolve(x[m], taps[m], "valid") for m in range(4))  # noqa: E731
    db = lambda x: 10 * math.log10(np.mean(np.asarray(x, float) ** 2))  # noqa: E731
    tv_down = db(tv[0, 3 * 16000:]) - db(through(tv[:, 3 * 16000:]))  # on sound not learnt from
    owner_down = db(said[0]) - db(through(said))  # from 55 degrees away: the lowest frequencies go too
    assert tv_down > 15 and tv_down - owner_down > 10
    # no source stands out in a quiet room: the first microphone as it is, DELAY late
    quiet = _house().receive_array(_mics(), 0.0, 2.0, mic="nao").astype(np.float64)
    plain = nulling_taps(quiet)
    assert np.allclose(plain[1:], 0) and np.argmax(plain[0]) == Steering.DELAY and plain[0].max() == pytest.approx(1)


@pytest.mark.parametrize("nulled", [True, False])
def test_the_owner_is_heard_over_a_loud_tv_only_with_the_tv_taken_out(nulled, monkeypatch):
    """At TV 60 the owner 3 m away is below the TV at every microphone: the detector on the first heard
    no utterance, or the TV's; behind the array's filter it cuts the owner's command."""
    if not nulled:
        monkeypatch.setattr(Steering, "_renew_filter", lambda self, vad: None)
    channels = _tv_and_owner(60, distance=3.0)
    vad, steering = VoiceActivity(max_seconds=5.0), Steering(NAO_MICS)
    cuts = [(u, end) for s in range(0, channels.shape[1], 1600)
            for u, end in steering.listen(vad, channels[:, s:s + 1600])]
    said = [(end / 16000 - u.seconds, end / 16000) for u, end in cuts if not u.too_long]
    owner = [(a, b) for a, b in said if a < 4.2 and b > 4.0 + len(SPEECH) / 16000]  # around the command
    assert bool(owner) == nulled, said
