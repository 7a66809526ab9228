"""A microphone array's signal processing: where a sound comes from, and the array steered there
(MVDR: the least noise power that passes the direction it is steered to unchanged), the noise
estimated from audio where nobody speaks. Positions are microphone offsets in metres from the
array's centre (a NAO's: robots/mic_array.py NAO_MICS); nothing here knows a room or a robot.

    azimuth, elevation = locate(channels, noise, offsets)      # (M, n) int16/float, the room's (M, k)
    out = mvdr(channels, noise, towards_delays(offsets, azimuth, elevation))   # one channel
    steering = Steering(offsets)                               # beside a voice detector (the Core's)
"""
from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import get_window, istft, oaconvolve, stft

from .acoustics import SPEED_OF_SOUND
from .wav import SAMPLE_RATE as RATE

if TYPE_CHECKING:
    from .vad import HeardUtterance, VoiceActivity

NFFT, HOP = 512, 128
# the detector's filter: centred this many samples in (its stream's lag), a whole number of the voice
# detector's 10 ms frames, so that they fall on the sound where they did on the first microphone
DETECTOR_DELAY = 320
DETECTOR_TAPS = 2 * DETECTOR_DELAY


def _spectra(x: np.ndarray, rate: int) -> np.ndarray:
    spectra: np.ndarray = stft(x, rate, nperseg=NFFT, noverlap=NFFT - HOP)[2]  # (M, F, T)
    return spectra


def _noise_covariance(noise: np.ndarray, loading: float, rate: int) -> np.ndarray:
    """Per frequency (F, M, M), with `loading` times the microphones' mean power added to each."""
    v = _spectra(noise, rate)
    phi = np.einsum("ift,jft->fij", v, v.conj()) / max(v.shape[2], 1)
    power = np.real(np.trace(phi, axis1=1, axis2=2)) / len(noise)
    covariance: np.ndarray = phi + (loading * power + 1e-12)[:, None, None] * np.eye(len(noise))
    return covariance


def _weights(phi: np.ndarray, steer: np.ndarray) -> np.ndarray:
    """MVDR weights (..., F, M) for steering vectors (..., F, M) against noise covariances (F, M, M)."""
    solved = np.linalg.solve(phi, steer[..., None])[..., 0]
    weights: np.ndarray = solved / np.einsum("...fm,...fm->...f", steer.conj(), solved)[..., None]
    return weights


def _steering(delays: np.ndarray, rate: int) -> np.ndarray:
    f = np.fft.rfftfreq(NFFT, 1 / rate)
    vectors: np.ndarray = np.exp(-2j * np.pi * f[:, None] * np.asarray(delays)[..., None, :])  # (..., F, M)
    return vectors


LOOK_BAND_HZ = (200.0, 4000.0)  # where speech has its power and the array's delays tell directions apart


@functools.lru_cache(maxsize=8)
def _look_directions(offsets: tuple[tuple[float, ...], ...], rate: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(azimuths, elevations, their steering vectors in the look band, the band) locate scans."""
    grid_az, grid_el = np.meshgrid(np.radians(np.arange(0, 360, 5)), np.radians(np.arange(0, 61, 15)), indexing="ij")
    az, el = grid_az.ravel(), grid_el.ravel()
    towards = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    delays = -(towards @ np.asarray(offsets).T) / SPEED_OF_SOUND  # (D, M): nearer microphones hear it earlier
    f = np.fft.rfftfreq(NFFT, 1 / rate)
    band = (f >= LOOK_BAND_HZ[0]) & (f <= LOOK_BAND_HZ[1])
    return az, el, _steering(delays, rate)[:, band], band


def locate(channels: np.ndarray, noise: np.ndarray, offsets: np.ndarray, loading: float = 1e-2,
           rate: int = RATE) -> tuple[float, float]:
    """(azimuth, elevation) in radians, in the house's frame, of the sound in `channels` that is not in
    `noise`: the direction from which an MVDR against the noise, steered there, passes the most power
    over the noise's (a scan of whole degrees of azimuth in 5, elevations 0-60 in 15, sources far away)."""
    return _locate(_spectra(channels, rate), _noise_covariance(noise, loading, rate), offsets, rate)


def _locate(x: np.ndarray, phi: np.ndarray, offsets: np.ndarray, rate: int) -> tuple[float, float]:
    az, el, steer, band = _look_directions(tuple(map(tuple, np.round(offsets, 6))), rate)
    inverse = np.linalg.inv(phi[band])
    x = x[:, band]
    heard = np.einsum("ift,jft->fij", x, x.conj()) / max(x.shape[2], 1)
    # what the speech adds over the noise in each direction, per frequency: an MVDR against the noise,
    # steered there, passes (d' N^-1 H N^-1 d) / (d' N^-1 d)^2 of what is heard and 1 / (d' N^-1 d) of
    # the noise (the TV's own direction passes the TV too: power alone would point there)
    gain = (np.real(np.einsum("dfi,fij,dfj->df", steer.conj(), inverse @ heard @ inverse, steer))
            / np.real(np.einsum("dfi,fij,dfj->df", steer.conj(), inverse, steer)))
    best = int(np.argmax(np.mean(np.log(gain), axis=1)))
    return float(az[best]), float(el[best])


DOMINANT = 2.0  # a frequency's strongest direction in the room's sound this much over the others' mean: one source


def nulling_taps(noise: np.ndarray, rate: int = RATE, dominant: float = DOMINANT) -> np.ndarray:
    """FIR filters (M, DETECTOR_TAPS), each centred at DETECTOR_DELAY, whose outputs summed over the
    microphones are the first microphone with the room's one dominant sound taken out: per frequency,
    what the microphones hear projected off the direction in which `noise` (M, k, where nobody speaks)
    has most of its power, where that power stands out `dominant` times over the other directions'
    mean (a TV: a point in an anechoic room, partly one in a furnished one); elsewhere the first
    microphone as it is. Needs no direction for the owner: a voice from elsewhere passes, less its
    lowest frequencies (where four microphones 8 cm apart hear every direction alike)."""
    v = _spectra(noise, rate)
    phi = np.einsum("ift,jft->fij", v, v.conj()) / max(v.shape[2], 1)
    power, vectors = np.linalg.eigh(phi)  # ascending
    top = vectors[:, :, -1]  # (F, M)
    one = power[:, -1] >= dominant * np.mean(power[:, :-1], axis=1)
    c = np.zeros(top.shape, complex)
    c[:, 0] = 1.0
    c[one] -= top[one, :1] * top[one].conj()  # row 0 of I - v v': (x - v v' x) at the first microphone
    taps = np.fft.irfft(c.T, NFFT, axis=1)
    out = np.zeros((len(taps), DETECTOR_TAPS))
    centred = np.roll(taps, NFFT // 2, axis=1) * get_window("hann", NFFT)
    out[:, DETECTOR_DELAY - NFFT // 2:DETECTOR_DELAY + NFFT // 2] = centred
    taps_out: np.ndarray = out
    return taps_out


def _as_it_is(shape: tuple[int, int]) -> np.ndarray:
    """nulling_taps where nothing stands out: the first microphone, DETECTOR_DELAY samples late."""
    taps = np.zeros(shape)
    taps[0, DETECTOR_DELAY] = 1.0
    return taps


def towards_delays(offsets: np.ndarray, azimuth: float, elevation: float) -> np.ndarray:
    """Seconds sound from a far source in that direction takes to each microphone, less the earliest."""
    u = np.array([math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation)])
    t = -(offsets @ u) / SPEED_OF_SOUND
    delays: np.ndarray = t - t.min()
    return delays


def mvdr(channels: np.ndarray, noise: np.ndarray, delays: np.ndarray, loading: float = 1e-2,
         rate: int = RATE) -> np.ndarray:
    """One channel from (M, n) `channels`: per frequency, the weights of least output power on `noise`
    (M, k: the same microphones where nobody speaks) that pass sound arriving with `delays` (s)
    unchanged. `loading` (share of the noise's mean power added to each microphone's) keeps the
    weights robust to a steering slightly off and to noise the estimate has not seen."""
    return _beam(_spectra(channels, rate), _noise_covariance(noise, loading, rate), delays, channels.shape[1], rate)


def _beam(x: np.ndarray, phi: np.ndarray, delays: np.ndarray, n: int, rate: int) -> np.ndarray:
    y = np.einsum("fm,mft->ft", _weights(phi, _steering(delays, rate)).conj(), x)
    _, out = istft(y, rate, nperseg=NFFT, noverlap=NFFT - HOP)
    beam: np.ndarray = out[:n].astype(np.float32)
    return beam


class Steering:
    """Beside a one-channel voice detector (hearing/vad.py VoiceActivity): every microphone's
    samples, kept HISTORY_S, so that an utterance the detector cuts can be heard again with the whole
    array: its direction found against the room's sound, and the array steered there (locate, mvdr).
    The room's sound is the last NOISE_S fed while the detector heard no speech (an earlier command in
    it would have the owner's own direction suppressed). The detector hears the first microphone with
    that sound's dominant source taken out (nulling_taps, renewed each NULL_EVERY_S), DELAY samples
    late: a loud TV otherwise hides the owner from it before any direction is known. Positions count
    samples fed, so the detector's cut finds its audio. It may outlive a listener, as its detector does:
    the room's sound before a task is still the room's when the owner speaks right after it."""

    HISTORY_S = 6.0  # an utterance (5 s at most, padded)
    NOISE_S = 3.0  # of the room's sound, the noise estimate
    MIN_NOISE_S = 1.0  # less known of the room: the utterance is left as the one microphone heard it
    NULL_EVERY_S = 1.0  # of new room's sound between the detector's filters
    CHANGED = 0.01  # a new filter this far (its energy's share) from the one in use replaces it
    DELAY = DETECTOR_DELAY  # samples the detector's stream lags the microphones

    def __init__(self, offsets: ArrayLike | None = None, rate: int = RATE):
        self.rate = rate
        self.offsets: np.ndarray | None = None
        self.fed = 0  # samples fed so far
        if offsets is not None:
            self._use(offsets)

    def _use(self, offsets: ArrayLike) -> None:
        self.offsets = np.asarray(offsets, float)
        self.kept: np.ndarray = np.zeros((len(self.offsets), 0), np.int16)
        self.noise: np.ndarray = np.zeros((len(self.offsets), 0), np.int16)
        self._pending: np.ndarray | None = None
        self.taps: np.ndarray | None = None  # the detector's filter (nulling_taps); None: the first microphone
        self._noise_new = round(self.NULL_EVERY_S * self.rate)  # room's sound since the filter was last judged
        self._tail = np.zeros((len(self.offsets), DETECTOR_TAPS - 1))

    def _follow(self, offsets: ArrayLike | None) -> None:
        """The microphones' offsets, where given: a new array forgets the old one's sound."""
        if offsets is not None and (self.offsets is None or not np.allclose(self.offsets, offsets)):
            self._use(offsets)

    def feed(self, channels: np.ndarray, quiet: bool, offsets: ArrayLike | None = None) -> None:
        """The samples whose first channel the detector was fed (`quiet`: it heard no speech in them);
        `offsets`: the microphones' (_follow)."""
        self._follow(offsets)
        self.kept = np.concatenate([self.kept, channels], axis=1)[:, -round(self.HISTORY_S * self.rate):]
        # a piece counts once the next is quiet too: the one before an utterance begins holds its onset
        # (the detector starts an utterance only after several loud frames)
        if quiet and self._pending is not None:
            self.noise = np.concatenate([self.noise, self._pending], axis=1)[:, -round(self.NOISE_S * self.rate):]
            self._noise_new += self._pending.shape[1]
        self._pending = channels if quiet else None
        self.fed += channels.shape[1]

    def _renew_filter(self, vad: VoiceActivity) -> None:
        """A new filter for the detector once NULL_EVERY_S more of the room's sound is known, while it
        hears no utterance; it relearns the room's sound as heard through the new filter."""
        if (self.offsets is None or len(self.offsets) < 2 or vad.active or self.noise.shape[1] < self.MIN_NOISE_S * self.rate
                or self._noise_new < self.NULL_EVERY_S * self.rate):
            return
        noise = self.noise.astype(np.float64)
        taps, self._noise_new = nulling_taps(noise, self.rate), 0
        before = self.taps if self.taps is not None else _as_it_is(taps.shape)
        # relearning costs the detector what it learnt over 5 s, and a steady room needs none
        if np.sum((taps - before) ** 2) > self.CHANGED * np.sum(taps ** 2):
            self.taps = taps
            vad.relearn_room(self._filtered(noise))

    def _filtered(self, x: np.ndarray) -> np.ndarray:
        """The detector's filter over (M, n) samples: n - DETECTOR_TAPS + 1 of them, int16."""
        taps = self.taps if self.taps is not None else _as_it_is((len(x), DETECTOR_TAPS))
        y = sum(oaconvolve(x[m], taps[m], "valid") for m in range(len(x)))
        out: np.ndarray = np.clip(np.round(y), -32768, 32767).astype(np.int16)
        return out

    def for_detector(self, channels: np.ndarray, offsets: ArrayLike | None = None) -> np.ndarray:
        """What the detector hears of these samples (int16, DELAY samples late): the first microphone,
        the room's dominant sound taken out once enough of it is known."""
        self._follow(offsets)
        buf = np.concatenate([self._tail, channels.astype(np.float64)], axis=1)
        self._tail = buf[:, buf.shape[1] - (DETECTOR_TAPS - 1):]
        if self.taps is None:
            return buf[0, self.DELAY - 1:self.DELAY - 1 + channels.shape[1]].astype(np.int16)
        return self._filtered(buf)

    def steered(self, samples: int, end: int) -> tuple[np.ndarray, float] | None:
        """(the beamformed int16 samples, azimuth in the robot's frame, radians) of the `samples` fed
        before sample `end`, or None where they are no longer kept or too little of the room's sound is
        known (CPU work: call from an executor)."""
        first, start = self.fed - self.kept.shape[1], end - samples
        if self.offsets is None or start < first or end > self.fed or self.noise.shape[1] < self.MIN_NOISE_S * self.rate:
            return None
        x = _spectra(self.kept[:, start - first:end - first].astype(np.float64), self.rate)
        phi = _noise_covariance(self.noise.astype(np.float64), 1e-2, self.rate)  # one estimate for both
        azimuth, elevation = _locate(x, phi, self.offsets, self.rate)
        out = _beam(x, phi, towards_delays(self.offsets, azimuth, elevation), samples, self.rate)
        return np.clip(np.round(out), -32768, 32767).astype(np.int16), azimuth

    def listen(self, vad: VoiceActivity, channels: np.ndarray,
               offsets: ArrayLike | None = None) -> list[tuple[HeardUtterance, int]]:
        """Feed the detector what it hears of these samples (for_detector) and this every channel
        (`offsets`: as for feed): the utterances it cut, as (utterance, its end counted in samples fed
        here), for `steered` (CPU work, a few ms: call from an executor)."""
        was_active = vad.active
        heard = vad.feed(self.for_detector(channels, offsets))
        self.feed(channels, quiet=not (was_active or vad.active or heard), offsets=offsets)
        self._renew_filter(vad)
        return [(u, self._end(vad, u)) for u in heard]

    def ending(self, vad: VoiceActivity) -> tuple[HeardUtterance, int] | None:
        """The utterance the detector will cut unless speech comes again (VoiceActivity.ending), as
        `listen` would give it, or None."""
        u = vad.ending()
        return None if u is None else (u, self._end(vad, u))

    def _end(self, vad: VoiceActivity, u: HeardUtterance) -> int:
        """The utterance's end counted in samples fed here."""
        # a detector that outlives listeners may have been fed before this was; it hears DELAY late
        return u.end_sample - (round(vad.heard_s * vad.rate) - self.fed) - self.DELAY
