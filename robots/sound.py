"""Sound in the simulated house: sources emit audio at a position, a microphone receives the mix.

Levels are physical: a source's signal is sound pressure (Pa) at 1 m; it falls off as 1/r (-6 dB per
doubling of distance), arrives after r / 343 m/s, and loses WALL_LOSS_DB for every wall and
DOOR_LOSS_DB for every closed door leaf on the straight line between source and microphone (the floor
plan's boxes; an open doorway lets sound through). A house described with `acoustics: {rt60_s: ...}`
adds each source's reverberation in the microphone's room (robots/reverb.py). Without it the house is
anechoic: a TV is far quieter at the robot than in a real room, a distant owner somewhat quieter
(docs/sound.md). A microphone turns pressure into 16 kHz mono int16 with FULL_SCALE_DB_SPL at full
scale, adds its own noise and clips. Every random signal (noise sources, microphone noise, echoes) is
drawn from the house's seed, the source or microphone name and the block index (an echo: the source
and the room), so a recording depends only on the seed and the schedule, not on how it is cut.

    house = house_sound(world)                         # one per World
    house.play("owner", (1.0, 2.4, 1.6), speech_int16, at=world.time, level_db=60)
    house.add(NoiseSource("tv", (0.3, 0.3, 0.8), kind="tv", level_db=65, seed=house.seed))
    pcm = house.receive((2.0, 2.4, 0.45), t0, seconds=2.0, mic="nao")   # int16, 16 kHz

What the robots and the Platform do with the sound they hear is hearing's (hearing/), and so are the
WAV helpers the robot API sends it with (hearing/wav.py)."""
from __future__ import annotations

import math
import threading
import weakref
import zlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.signal import fftconvolve, resample_poly

from hearing.acoustics import SPEED_OF_SOUND
from hearing.errors import BadAudio
from hearing.wav import SAMPLE_RATE
from ontology.errors import ErrorCode

from .mic_array import diffuse
from .reverb import tail

if TYPE_CHECKING:
    from .floorplan import Box, Plan

REF_PA = 20e-6  # 0 dB SPL
FULL_SCALE_DB_SPL = 100.0  # the microphone's int16 full scale (a close shout; speech at 1 m is ~60)
MIC_NOISE_DB_SPL = 28.0  # self-noise of a small robot microphone
WALL_LOSS_DB = 25.0  # an interior partition wall, broadband
DOOR_LOSS_DB = 15.0  # a closed interior door leaf
MIN_DISTANCE = 0.1  # m: nothing is closer to a microphone than its own housing allows
BLOCK = SAMPLE_RATE  # samples per seeded noise block
CAPTURE_RATES = (8000, 16000)


def db_spl_to_pa(db: float) -> float:
    return REF_PA * 10 ** (db / 20)


PA_PER_DIGIT = db_spl_to_pa(FULL_SCALE_DB_SPL) * math.sqrt(2) / 32767  # full-scale sine = FULL_SCALE dB


def _rng(seed: int, name: str, block: int) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(name.encode()), block])


# ---------------------------------------------------------------------------------------- sources
@dataclass
class SoundSource:
    """Something that emits sound at `position` from simulation time `start` (until `stop`, None = on)."""

    id: str
    position: tuple[float, float, float]
    start: float = 0.0
    stop: float | None = None

    def signal(self, i0: int, n: int) -> np.ndarray:
        """Pressure (Pa at 1 m) of samples i0 .. i0+n-1 counted from `start`; zeros where silent."""
        raise NotImplementedError

    def end(self) -> float | None:
        return self.stop


@dataclass
class Clip(SoundSource):
    """A recorded sound (an utterance, the robot's loudspeaker): `pressure` in Pa at 1 m."""

    pressure: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    loop: bool = False

    def signal(self, i0: int, n: int) -> np.ndarray:
        out = np.zeros(n, np.float32)
        length = len(self.pressure)
        if length == 0:
            return out
        idx = np.arange(i0, i0 + n)
        if self.loop:
            ok = idx >= 0
            out[ok] = self.pressure[idx[ok] % length]
        else:
            ok = (idx >= 0) & (idx < length)
            out[ok] = self.pressure[idx[ok]]
        return out

    def end(self) -> float | None:
        own = None if self.loop else self.start + len(self.pressure) / SAMPLE_RATE
        ends = [e for e in (own, self.stop) if e is not None]
        return min(ends) if ends else None


NOISE_KINDS = ("tv", "radio", "white", "hum")


@dataclass
class NoiseSource(SoundSource):
    """A television, radio or appliance: seeded noise shaped like its kind, `level_db` SPL at 1 m.
    tv: pink noise in the speech band, modulated at syllable rate (voices, music); radio: the same,
    steadier; white: broadband; hum: 50 Hz mains hum with harmonics."""

    kind: str = "tv"
    level_db: float = 65.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.kind not in NOISE_KINDS:
            raise BadAudio(f"unknown noise kind {self.kind!r} (known: {', '.join(NOISE_KINDS)})",
                           ErrorCode.INVALID_ARGUMENT)

    def _block(self, b: int) -> np.ndarray:
        rng = _rng(self.seed, f"noise:{self.id}", b)
        if self.kind == "hum":
            t = (np.arange(BLOCK) + b * BLOCK) / SAMPLE_RATE
            x = sum(np.sin(2 * np.pi * 50 * k * t) / k for k in (1, 2, 3, 5))
        else:
            spec = rng.normal(size=BLOCK // 2 + 1) + 1j * rng.normal(size=BLOCK // 2 + 1)
            f = np.fft.rfftfreq(BLOCK, 1 / SAMPLE_RATE)
            if self.kind != "white":
                band = (f > 150) & (f < 5000)
                spec = spec * np.where(band, 1 / np.sqrt(np.maximum(f, 1.0)), 0.0)
            x = np.fft.irfft(spec, BLOCK)
            if self.kind in ("tv", "radio"):
                depth = 0.8 if self.kind == "tv" else 0.3
                t = np.arange(BLOCK) / SAMPLE_RATE
                rate = rng.uniform(3.0, 6.0)
                x = x * (1 - depth / 2 + depth / 2 * np.sin(2 * np.pi * rate * t + rng.uniform(0, 2 * np.pi)))
        x = x / (np.sqrt(np.mean(x ** 2)) + 1e-12)
        return (x * db_spl_to_pa(self.level_db)).astype(np.float32)

    def signal(self, i0: int, n: int) -> np.ndarray:
        out = np.zeros(n, np.float32)
        lo, hi = max(i0, 0), i0 + n
        if hi <= lo:
            return out
        for b in range(lo // BLOCK, (hi - 1) // BLOCK + 1):
            s, e = max(lo, b * BLOCK), min(hi, (b + 1) * BLOCK)
            out[s - i0:e - i0] = self._block(b)[s - b * BLOCK:e - b * BLOCK]
        return out


def clip_from_pcm(source_id: str, position, pcm: np.ndarray, at: float, level_db: float | None = 60.0,
                  full_scale_db: float = 90.0, loop: bool = False) -> Clip:
    """A Clip from int16 samples (16 kHz): scaled so its active part is `level_db` SPL at 1 m, or, with
    level_db=None, as a loudspeaker plays it (a full-scale sine is `full_scale_db` SPL at 1 m)."""
    x = np.asarray(pcm, np.float32)
    if level_db is None:
        scale = db_spl_to_pa(full_scale_db) * math.sqrt(2) / 32767
    else:
        active = x[np.abs(x) > 0.02 * (np.abs(x).max(initial=0.0) + 1e-12)]
        rms = float(np.sqrt(np.mean(active ** 2))) if active.size else 0.0
        scale = db_spl_to_pa(level_db) / rms if rms > 0 else 0.0
    return Clip(source_id, tuple(map(float, position)), float(at), pressure=(x * scale).astype(np.float32), loop=loop)


# ---------------------------------------------------------------------------------------- walls
def _crosses(box: "Box", a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Does the segment a-b pass through the box footprint (Liang-Barsky in the box frame)?"""
    c, s = math.cos(box.yaw), math.sin(box.yaw)

    def local(p):
        dx, dy = p[0] - box.x, p[1] - box.y
        return c * dx + s * dy, -s * dx + c * dy

    (x0, y0), (x1, y1) = local(a), local(b)
    dx, dy = x1 - x0, y1 - y0
    t0, t1 = 0.0, 1.0
    for pp, q in ((-dx, x0 + box.sx / 2), (dx, box.sx / 2 - x0), (-dy, y0 + box.sy / 2), (dy, box.sy / 2 - y0)):
        if pp == 0:
            if q < 0:
                return False
            continue
        r = q / pp
        if pp < 0:
            t0 = max(t0, r)
        else:
            t1 = min(t1, r)
        if t0 > t1:
            return False
    return t1 - t0 > 1e-9


# ---------------------------------------------------------------------------------------- the house
class HouseSound:
    """Every sound source of one house and what a microphone at a position receives."""

    def __init__(self, plan: "Plan", seed: int | None = None):
        self.plan = plan
        self.seed = plan.seed if seed is None else seed
        self.sources: dict[str, SoundSource] = {}
        self._lock = threading.Lock()  # sources are added from the event loop, mixed in executors
        self._tails: dict[tuple[str, str], np.ndarray] = {}  # (source, room) -> reverberant taps

    # ---- sources
    def add(self, source: SoundSource) -> SoundSource:
        with self._lock:
            self.sources[source.id] = source
        return source

    def remove(self, source_id: str) -> None:
        with self._lock:
            self.sources.pop(source_id, None)
            self._forget_tails({source_id})

    def _forget_tails(self, source_ids: set[str]) -> None:  # under the lock
        for key in [k for k in self._tails if k[0] in source_ids]:
            del self._tails[key]

    def play(self, source_id: str, position, pcm: np.ndarray, at: float, level_db: float | None = 60.0,
             full_scale_db: float = 90.0) -> Clip:
        """Schedule a recording (16 kHz samples) at `position` from simulation time `at` (levels: clip_from_pcm)."""
        return self.add(clip_from_pcm(source_id, position, pcm, at, level_db, full_scale_db))  # type: ignore[return-value]

    def prune(self, before: float) -> None:
        """Forget sources that fell silent before `before` (simulation seconds; their echo too: pass a
        time longer than the room's reverberation ago)."""
        with self._lock:
            gone = {k for k, s in self.sources.items() if (s.end() or math.inf) < before}
            for k in gone:
                del self.sources[k]
            self._forget_tails(gone)

    # ---- propagation
    def walls_between(self, a, b) -> tuple[int, int]:
        """(walls, closed door leaves) on the straight line between two points."""
        p, q = (a[0], a[1]), (b[0], b[1])
        walls = sum(_crosses(w, p, q) for w in self.plan.walls)
        doors = sum(_crosses(d.leaf_box(), p, q) for d in self.plan.doors)
        return walls, doors

    def gain(self, source_pos, mic_pos) -> float:
        """Pressure at the microphone per Pa at 1 m from the source."""
        return self._wall_loss(source_pos, mic_pos) / max(math.dist(source_pos, mic_pos), MIN_DISTANCE)

    def _wall_loss(self, source_pos, mic_pos) -> float:
        """The pressure the walls and closed doors between let through (1: none between)."""
        walls, doors = self.walls_between(source_pos, mic_pos)
        return 10 ** (-(walls * WALL_LOSS_DB + doors * DOOR_LOSS_DB) / 20)

    def pressure(self, mic_pos, t0: float, seconds: float) -> np.ndarray:
        """Sound pressure (Pa) at `mic_pos` for [t0, t0 + seconds), every source mixed, no microphone."""
        i0, n = round(t0 * SAMPLE_RATE), round(seconds * SAMPLE_RATE)
        out = np.zeros(n, np.float32)
        with self._lock:
            sources = list(self.sources.values())
        for s in sources:
            end = s.end()
            delay_s = math.dist(s.position, mic_pos) / SPEED_OF_SOUND
            taps = self._tail(s, mic_pos)
            lasts = delay_s + len(taps) / SAMPLE_RATE  # after the source's end, the sound still arriving
            if s.start >= t0 + seconds or (end is not None and end + lasts <= t0):
                continue
            delay, loss = round(delay_s * SAMPLE_RATE), self._wall_loss(s.position, mic_pos)
            out += loss / max(delay_s * SPEED_OF_SOUND, MIN_DISTANCE) * _arriving(s, i0 - delay, n)
            if len(taps):  # the room's echo of it, through the same walls (simply)
                x = _arriving(s, i0 - delay - len(taps) + 1, n + len(taps) - 1)
                out += (loss * fftconvolve(x, taps, mode="valid")).astype(np.float32)
        return out

    def pressure_array(self, mics, t0: float, seconds: float) -> np.ndarray:
        """pressure() at several microphones at once (M, n): each hears the direct sound after its own
        delay (to a fraction of a sample: robots/mic_array.py steers by these), the room's echo as a
        diffuse field, coherent between them as close microphones hear it (mic_array.diffuse)."""
        mics = np.asarray(mics, float)
        centre = tuple(mics.mean(axis=0))
        i0, n = round(t0 * SAMPLE_RATE), round(seconds * SAMPLE_RATE)
        out = np.zeros((len(mics), n), np.float32)
        with self._lock:
            sources = list(self.sources.values())
        for s in sources:
            end, dists = s.end(), np.linalg.norm(mics - np.asarray(s.position, float)[None], axis=1)
            taps = self._tails_at(s, mics, centre)
            lasts = dists.max() / SPEED_OF_SOUND + taps.shape[1] / SAMPLE_RATE
            if s.start >= t0 + seconds or (end is not None and end + lasts <= t0):
                continue
            loss = self._wall_loss(s.position, centre)
            for k, r in enumerate(dists):
                out[k] += loss / max(r, MIN_DISTANCE) * _delayed(s, i0, n, r / SPEED_OF_SOUND)
            if taps.shape[1]:
                delay = round(math.dist(s.position, centre) / SPEED_OF_SOUND * SAMPLE_RATE)
                x = _arriving(s, i0 - delay - taps.shape[1] + 1, n + taps.shape[1] - 1)
                for k in range(len(mics)):
                    out[k] += (loss * fftconvolve(x, taps[k], mode="valid")).astype(np.float32)
        return out

    def receive_array(self, mics, t0: float, seconds: float, mic: str = "mic",
                      noise_db: float = MIC_NOISE_DB_SPL) -> np.ndarray:
        """receive() at several microphones (M, n) int16, 16 kHz, each with noise of its own."""
        pa = self.pressure_array(mics, t0, seconds)
        i0 = round(t0 * SAMPLE_RATE)
        digits = pa / PA_PER_DIGIT + np.stack([self._mic_noise(f"{mic}:{k}", i0, pa.shape[1], noise_db)
                                               for k in range(len(pa))])
        return np.clip(np.round(digits), -32768, 32767).astype(np.int16)

    def _tails_at(self, source: SoundSource, mics: np.ndarray, centre) -> np.ndarray:
        """_tail for each of several close microphones, coherent as a diffuse field's (M, L)."""
        room = self.plan.room_at(centre[0], centre[1]) if self.plan.rt60_s > 0 else None
        if room is None:
            return np.zeros((len(mics), 0), np.float32)
        offsets = mics - np.asarray(centre)[None]
        key = (source.id, room, tuple(np.round(offsets, 4).ravel()))
        taps = self._tails.get(key)
        if taps is None:
            volume = self.plan.room_volume(room)
            each = np.stack([tail(self.plan.rt60_s, volume, _rng(self.seed, f"reverb:{source.id}:{room}:{k}", 0))
                             for k in range(len(mics))])
            taps = diffuse(each, offsets)
            with self._lock:
                self._tails[key] = taps
        return taps

    def _tail(self, source: SoundSource, mic_pos) -> np.ndarray:
        """The reverberant impulse response of the room the microphone is in (none: anechoic, or the
        microphone in no room), seeded per source and room."""
        room = self.plan.room_at(mic_pos[0], mic_pos[1]) if self.plan.rt60_s > 0 else None
        if room is None:
            return _NO_TAIL
        key = (source.id, room)
        taps = self._tails.get(key)
        if taps is None:
            taps = tail(self.plan.rt60_s, self.plan.room_volume(room), _rng(self.seed, f"reverb:{source.id}:{room}", 0))
            with self._lock:  # mixed in executors; remove and prune forget tails under it
                self._tails[key] = taps
        return taps

    def receive(self, mic_pos, t0: float, seconds: float, mic: str = "mic", rate: int = SAMPLE_RATE,
                noise_db: float = MIC_NOISE_DB_SPL) -> np.ndarray:
        """What microphone `mic` at `mic_pos` records over [t0, t0 + seconds): int16 at `rate`."""
        if rate not in CAPTURE_RATES:
            raise BadAudio(f"sample rate {rate} Hz not supported (use {' or '.join(map(str, CAPTURE_RATES))})",
                           ErrorCode.UNSUPPORTED)
        pa = self.pressure(mic_pos, t0, seconds)
        digits = pa / PA_PER_DIGIT + self._mic_noise(mic, round(t0 * SAMPLE_RATE), len(pa), noise_db)
        if rate != SAMPLE_RATE:
            digits = resample_poly(digits, rate, SAMPLE_RATE)
        return np.clip(np.round(digits), -32768, 32767).astype(np.int16)

    def _mic_noise(self, mic: str, i0: int, n: int, noise_db: float) -> np.ndarray:
        sigma = db_spl_to_pa(noise_db) / PA_PER_DIGIT
        out = np.empty(n, np.float32)
        for b in range(i0 // BLOCK, (i0 + n - 1) // BLOCK + 1) if n else ():
            s, e = max(i0, b * BLOCK), min(i0 + n, (b + 1) * BLOCK)
            block = _rng(self.seed, f"mic:{mic}", b).normal(0.0, sigma, BLOCK)
            out[s - i0:e - i0] = block[s - b * BLOCK:e - b * BLOCK]
        return out


_NO_TAIL = np.zeros(0, np.float32)


def _arriving(s: SoundSource, first: int, n: int) -> np.ndarray:
    """n samples of what `s` emits from sample `first` of the house's time on (silence before its start
    and after its stop)."""
    x = s.signal(first - round(s.start * SAMPLE_RATE), n)
    if s.stop is not None:  # a source switched off mid-window
        x[np.arange(n) + first >= round(s.stop * SAMPLE_RATE)] = 0.0
    return x


FRACTION_TAPS = 16  # each side of a fractional delay's windowed sinc


def _delayed(s: SoundSource, i0: int, n: int, delay_s: float) -> np.ndarray:
    """n samples of `s` as heard from sample i0 on, `delay_s` after it emitted them (a windowed sinc
    interpolates between samples)."""
    whole = math.floor(delay_s * SAMPLE_RATE)
    frac, k = delay_s * SAMPLE_RATE - whole, np.arange(-FRACTION_TAPS, FRACTION_TAPS + 1)
    h = np.sinc(k - frac) * (0.5 + 0.5 * np.cos(np.pi * (k - frac) / (FRACTION_TAPS + 1)))
    x = _arriving(s, i0 - whole - FRACTION_TAPS, n + 2 * FRACTION_TAPS)
    return np.convolve(x, h, mode="valid").astype(np.float32)


_HOUSES: "weakref.WeakKeyDictionary[object, HouseSound]" = weakref.WeakKeyDictionary()
_HOUSES_LOCK = threading.Lock()


def talker_at(listener_xy: tuple[float, float], distance: float, ear_z: float,
               direction: tuple[float, float] = (0.55, 0.835)) -> tuple[float, float, float]:
    """Where a person's mouth is when they talk `distance` m from a microphone at height `ear_z`,
    along `direction` (a unit vector) in the floor plane; seated for the short distances."""
    dz = min(0.7, 0.8 * distance)
    h = math.sqrt(distance ** 2 - dz ** 2)
    return listener_xy[0] + direction[0] * h, listener_xy[1] + direction[1] * h, ear_z + dz


def house_sound(world) -> HouseSound:
    """The sound of a World's house (made on first use, lives as long as the world)."""
    with _HOUSES_LOCK:
        house = _HOUSES.get(world)
        if house is None:
            house = _HOUSES[world] = HouseSound(world.plan)
        return house
