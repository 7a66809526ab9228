"""A room's reverberation, statistically: what an anechoic house leaves out (robots/sound.py).

Sabine's room acoustics: a room of volume V (m^3) whose sound dies away by 60 dB in RT60 seconds has a
critical distance r_c = 0.057 sqrt(V / RT60) m, where a source's reverberant sound is as loud as its
direct sound; beyond it the reverberation is the louder. The reverberant part is a diffuse field, about
as loud anywhere in the room: 1 / r_c^2 of the source's energy at 1 m. Its impulse response is
modelled as Polack's: white noise decaying exponentially (-60 dB at RT60) from the direct sound's
arrival. Early reflections are not modelled apart, nor the room's shape, furniture or absorption by
frequency: a living room's RT60 is 0.3-0.6 s, about flat over the speech band.

    taps = tail(rt60_s=0.5, volume_m3=32.0, rng=rng)   # float32, energy 1 / r_c^2
"""
from __future__ import annotations

import math

import numpy as np

RT60_MAX_S = 3.0  # a church; a house's rooms are far below


def critical_distance(volume_m3: float, rt60_s: float) -> float:
    """Where direct and reverberant sound are equally loud (m)."""
    return 0.057 * math.sqrt(volume_m3 / rt60_s)


def tail(rt60_s: float, volume_m3: float, rng: np.random.Generator, rate: int = 16000) -> np.ndarray:
    """The reverberant impulse response per Pa at 1 m from the source, from the direct sound on."""
    n = max(1, round(rt60_s * rate))
    h = rng.normal(size=n) * np.exp(-math.log(1000.0) * np.arange(n) / n)  # amplitude -60 dB at RT60
    return (h / (math.sqrt(float(np.sum(h ** 2))) * critical_distance(volume_m3, rt60_s))).astype(np.float32)


def checked_rt60(value) -> float:
    """A house description's `acoustics: {rt60_s: ...}`, or a clear error."""
    try:
        rt60 = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"acoustics.rt60_s must be a number of seconds, not {value!r}") from None
    if not 0.0 <= rt60 <= RT60_MAX_S:
        raise ValueError(f"acoustics.rt60_s {rt60} is outside 0..{RT60_MAX_S} s (0: no reverberation)")
    return rt60
