"""Audio as it crosses a wire: 16-bit PCM WAV in and out, and a recording's level. The robot API
and the Platform's speech services exchange audio as WAV.

    data = encode_wav(pcm)                         # (n,) mono or (channels, n) int16 -> bytes
    pcm, rate = decode_wav(data, channels=4)       # BadAudio for anything else
    rms_db, peak_db = level_dbfs(pcm)
"""
from __future__ import annotations

import io
import math
import wave

import numpy as np

from ontology.errors import ErrorCode

from .errors import BadAudio

SAMPLE_RATE = 16000  # what every recogniser here takes, and what the house's microphones record


def level_dbfs(pcm: np.ndarray) -> tuple[float, float]:
    """(rms, peak) of int16 samples in dB relative to full scale (-120 for digital silence)."""
    x = np.asarray(pcm, np.float64) / 32768.0
    if x.size == 0:
        return -120.0, -120.0
    rms, peak = math.sqrt(float(np.mean(x ** 2))), float(np.abs(x).max())
    return max(20 * math.log10(rms + 1e-12), -120.0), max(20 * math.log10(peak + 1e-12), -120.0)


def encode_wav(pcm: np.ndarray, rate: int = SAMPLE_RATE) -> bytes:
    """A 16-bit PCM WAV of int16 samples: (n,) mono, or (channels, n), interleaved."""
    pcm = np.asarray(pcm)
    channels = 1 if pcm.ndim == 1 else pcm.shape[0]
    if pcm.ndim == 2:
        pcm = pcm.T.ravel()
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(channels)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(np.asarray(pcm, "<i2").tobytes())
    return buf.getvalue()


def decode_wav(data: bytes, rates: tuple[int, ...] = (SAMPLE_RATE,), max_seconds: float = 60.0,
               channels: int = 1) -> tuple[np.ndarray, int]:
    """(int16 samples, rate) of a mono 16-bit PCM WAV, or with `channels` > 1 one of that many channels
    ((channels, n) samples); BadAudio for anything else. The header is checked before any sample is
    read, so an over-long recording costs nothing."""
    try:
        with wave.open(io.BytesIO(data), "rb") as w:
            got, width, rate, frames = w.getnchannels(), w.getsampwidth(), w.getframerate(), w.getnframes()
            if got != channels or width != 2:
                kind = "mono" if channels == 1 else f"{channels}-channel"
                raise BadAudio(f"need {kind} 16-bit PCM, got {got} channel(s) of {8 * width} bit",
                               ErrorCode.UNSUPPORTED)
            if rate not in rates:
                raise BadAudio(f"sample rate {rate} Hz not supported (use {' or '.join(map(str, rates))})",
                               ErrorCode.UNSUPPORTED)
            if frames / rate > max_seconds:
                raise BadAudio(f"recording of {frames / rate:.1f} s exceeds the limit of {max_seconds:g} s",
                               ErrorCode.TOO_LARGE)
            raw = w.readframes(frames)
    except (wave.Error, EOFError) as e:
        raise BadAudio(f"not a WAV file: {e}", ErrorCode.MALFORMED) from None
    if len(raw) % 2:
        raw = raw[:-1]
    pcm = np.frombuffer(raw, "<i2").astype(np.int16)
    if channels > 1:
        pcm = pcm[:len(pcm) // channels * channels].reshape(-1, channels).T.copy()
    return pcm, rate
