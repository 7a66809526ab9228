"""Band spectra of the microphone's 10 ms frames, for voice activity detection (hearing/vad.py,
VoiceActivity): a TV's sound swells and fades but keeps its spectrum; a voice over it changes it.

Nothing here knows what a source played: only the microphone's int16 samples at 16 kHz come in.

    bands = BandSpectra()
    logb = bands.feed_frames(frames)   # frames: (n, 160) int16 -> (n, 16) band powers in dB

Denoising before the recognisers (a Wiener gain from the noise of the microphone's recent non-speech
audio, as the original RAPP denoised before Sphinx) was measured on the speech benchmark's commands
and left out: it cost more words than it saved (bench/RESULTS.md, Speech).
"""
from __future__ import annotations

import numpy as np

RATE = 16000
HOP = RATE // 100  # 10 ms
WINDOW = 400  # 25 ms analysis window per 10 ms frame
NFFT = 512
BAND_EDGES_HZ = np.geomspace(150.0, 5000.0, 17)  # 16 bands over the speech band, log spaced


def _band_matrix(nfft: int = NFFT, edges: np.ndarray = BAND_EDGES_HZ) -> np.ndarray:
    f = np.fft.rfftfreq(nfft, 1 / RATE)
    m = np.stack([(f >= lo) & (f < hi) for lo, hi in zip(edges[:-1], edges[1:])]).astype(np.float64)
    bands: np.ndarray = m / m.sum(axis=1, keepdims=True)
    return bands


_BANDS = _band_matrix()
_WIN = np.hanning(WINDOW)


class BandSpectra:
    """Streaming log band powers: each 10 ms hop gets the power of the last 25 ms in 16 bands (dB)."""

    def __init__(self) -> None:
        self._tail = np.zeros(WINDOW - HOP)

    def feed_frames(self, frames: np.ndarray) -> np.ndarray:
        """frames: (n, HOP) samples, in order -> (n, bands) dB."""
        if len(frames) == 0:
            return np.zeros((0, _BANDS.shape[0]))
        x = np.concatenate([self._tail, frames.astype(np.float64).ravel()])
        self._tail = x[-(WINDOW - HOP):]
        idx = np.arange(len(frames))[:, None] * HOP + np.arange(WINDOW)[None, :]
        spec = np.abs(np.fft.rfft(x[idx] * _WIN, NFFT, axis=1)) ** 2
        db: np.ndarray = 10 * np.log10(spec @ _BANDS.T + 1.0)
        return db
