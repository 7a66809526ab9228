"""Several microphones on one simulated head: where they are, and how the house's sound reaches them.

A NAO has four microphones on its head (capture_audio with `array`: robots/microphones.py AudioInput
record_array). Here: where the four are (NAO_MICS, approximate: a 8 x 6-10 cm layout on the head's
top, not the maker's drawing), where they are in the house as the head turns, the delays a sound's
way to each takes, and the coherence their reverberant sound has (a diffuse field's: sinc of the
spacing, so an array cannot cancel it as it would independent noise). What a listener does with the
channels (locate, beamform, the detector's filter) is hearing's: hearing/steering.py.

    offsets = heads_mics(NAO_MICS, heading)                    # (4, 3) m, from the head's centre
    coherent = diffuse(tails, offsets)                         # (4, n) reverberant tails
    delays = arrival_delays(offsets + head, source)            # s, for hearing.steering.mvdr
"""
from __future__ import annotations

import math

import numpy as np

from hearing.acoustics import SPEED_OF_SOUND
from hearing.wav import SAMPLE_RATE as RATE

# (forward, left, up) m from the head's centre, where robots/microphones.py AudioInput puts its one microphone
NAO_MICS = ((0.040, 0.030, 0.0), (0.040, -0.030, 0.0), (-0.040, 0.050, 0.0), (-0.040, -0.050, 0.0))


def heads_mics(offsets, heading: float) -> np.ndarray:
    """The microphones' offsets in the house's frame, the head turned `heading` radians."""
    c, s = math.cos(heading), math.sin(heading)
    return np.array([(c * x - s * y, s * x + c * y, z) for x, y, z in offsets], float)


def diffuse(tails: np.ndarray, offsets: np.ndarray, rate: int = RATE) -> np.ndarray:
    """Independent reverberant tails (M, n), one per microphone, mixed per frequency so that each pair's
    coherence is a diffuse field's, sinc(2 f d / c) at spacing d; each keeps its own energy."""
    m, n = tails.shape
    spectra = np.fft.rfft(tails, axis=1)
    f = np.fft.rfftfreq(n, 1 / rate)
    d = np.linalg.norm(offsets[:, None, :] - offsets[None, :, :], axis=2)
    gamma = np.sinc(2 * f[:, None, None] * d[None] / SPEED_OF_SOUND) + 1e-6 * np.eye(m)
    mix = np.linalg.cholesky(gamma)  # (F, M, M), rows of unit norm
    return np.fft.irfft(np.einsum("fij,jf->if", mix, spectra), n, axis=1).astype(np.float32)


def arrival_delays(mics: np.ndarray, source) -> np.ndarray:
    """Seconds sound from `source` takes to each microphone (positions in m), less the earliest."""
    t = np.linalg.norm(mics - np.asarray(source, float)[None], axis=1) / SPEED_OF_SOUND
    return t - t.min()

