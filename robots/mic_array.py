"""Several microphones on one head, and a beamformer over them (measured offline only so far:
bench/speech_offline.py `--mics`).

A NAO has four microphones on its head; the Core listens to one (robots/receptors.py AudioInput).
Here: where the four are (NAO_MICS, approximate: a 8 x 6-10 cm layout on the head's top, not the
maker's drawing), the coherence their reverberant sound has (a diffuse field's: sinc of the spacing,
so the array cannot cancel it as it would independent noise), and a beamformer (MVDR: the least
noise power that passes the direction it is steered to unchanged), whose noise is estimated from
audio where nobody speaks.

    offsets = heads_mics(NAO_MICS, heading)                    # (4, 3) m, from the head's centre
    coherent = diffuse(tails, offsets)                         # (4, n) reverberant tails
    out = mvdr(channels, noise, arrival_delays(offsets, src))  # one channel
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import istft, stft

SPEED_OF_SOUND = 343.0
RATE = 16000
# (forward, left, up) m from the head's centre, where robots/receptors.py AudioInput puts its one microphone
NAO_MICS = ((0.040, 0.030, 0.0), (0.040, -0.030, 0.0), (-0.040, 0.050, 0.0), (-0.040, -0.050, 0.0))
NFFT, HOP = 512, 128


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


def mvdr(channels: np.ndarray, noise: np.ndarray, delays: np.ndarray, loading: float = 1e-2,
         rate: int = RATE) -> np.ndarray:
    """One channel from (M, n) `channels`: per frequency, the weights of least output power on `noise`
    (M, k: the same microphones where nobody speaks) that pass sound arriving with `delays` (s)
    unchanged. `loading` (share of the noise's mean power added to each microphone's) keeps the
    weights robust to a steering slightly off and to noise the estimate has not seen."""
    m = channels.shape[0]
    _, _, x = stft(channels, rate, nperseg=NFFT, noverlap=NFFT - HOP)  # (M, F, T)
    _, _, v = stft(noise, rate, nperseg=NFFT, noverlap=NFFT - HOP)
    f = np.fft.rfftfreq(NFFT, 1 / rate)
    phi = np.einsum("ift,jft->fij", v, v.conj()) / max(v.shape[2], 1)
    power = np.real(np.trace(phi, axis1=1, axis2=2)) / m
    phi = phi + (loading * power + 1e-12)[:, None, None] * np.eye(m)
    steer = np.exp(-2j * np.pi * f[:, None] * np.asarray(delays)[None, :])  # (F, M)
    solved = np.linalg.solve(phi, steer[:, :, None])[:, :, 0]
    w = solved / np.einsum("fm,fm->f", steer.conj(), solved)[:, None]
    y = np.einsum("fm,mft->ft", w.conj(), x)
    _, out = istft(y, rate, nperseg=NFFT, noverlap=NFFT - HOP)
    return out[:channels.shape[1]].astype(np.float32)
