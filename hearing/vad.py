"""Voice activity: where in a stream of 16 kHz int16 sound someone speaks, and the utterances cut
from it.

    vad = VoiceActivity(max_seconds=5.0)          # the Core's continuous listening
    for utterance in vad.feed(chunk): ...         # HeardUtterance: pcm, speech_seconds, loud, end_sample
    ahead = vad.ending()                          # the utterance it will cut unless speech comes again

    speech_segments(pcm)                          # a whole recording's speech, by level alone (word spotting)
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from .bands import BandSpectra
from .errors import InvalidArgument


def frame_levels(frames: np.ndarray) -> np.ndarray:
    """Each 10 ms frame's level (n, hop) -> (n,) dB of its mean square (+1: silence is 0 dB)."""
    levels: np.ndarray = 10 * np.log10(np.mean(np.asarray(frames, np.float64) ** 2, axis=1) + 1.0)
    return levels


def speech_segments(pcm: np.ndarray, rate: int = 16000, margin_db: float = 9.0, min_speech: float = 0.15,
                    max_gap: float = 0.35, pad: float = 0.2) -> list[tuple[int, int]]:
    """Sample ranges where someone speaks: 10 ms frames louder than the recording's own floor (its
    20th percentile, so a steady TV or fan raises the bar) by `margin_db`, gaps up to `max_gap` bridged."""
    hop = rate // 100
    n = len(pcm) // hop
    if n == 0:
        return []
    db = frame_levels(pcm[:n * hop].reshape(n, hop))
    loud = db > np.percentile(db, 20) + margin_db
    runs, start, quiet = [], None, 0
    for i, v in enumerate(loud):
        if v:
            start = i if start is None else start
            quiet = 0
        elif start is not None:
            quiet += 1
            if quiet * hop > max_gap * rate:
                runs.append((start, i - quiet + 1))
                start, quiet = None, 0
    if start is not None:
        runs.append((start, n - quiet))
    p = int(pad * rate)
    return [(max(0, s * hop - p), min(len(pcm), e * hop + p)) for s, e in runs if (e - s) * hop >= min_speech * rate]


class VoiceActivity:
    """Streaming voice activity detection on 16 kHz int16 chunks (the Core's continuous listening).

    A 10 ms frame is speech when it stands out from the room's recent non-speech sound (the last
    `floor_seconds` of frames outside utterances) in either of two ways:
      level: louder than that sound's `level_pct` percentile by `margin_db` (a steady fan or the mic's
             own noise is beaten by any voice near enough);
      shape: its 16 band spectrum (hearing/bands.py), level removed, departs from the noise's usual
             band shape more than nine in ten of the noise's own frames do (`shape_pct` percentile,
             + `shape_margin_db`): a TV's sound swells and fades with its programme but keeps its
             spectrum; a voice over it changes the spectrum even where it is no louder.
    An utterance starts after `start_frames` speech frames in a row and ends after `end_silence` s
    without; once that silence has lasted `resume_after` s, only `resume_frames` speech frames in a
    row end it (the mic's own noise alone passes for speech in ~3 % of its frames, most of them one
    at a time, and each held an utterance open up to 0.3 s longer). `feed` returns the finished ones
    (with `pad` s of audio before and after). One longer than `max_seconds` is returned once, cut,
    with `too_long` set, and the rest of it is skipped."""

    def __init__(self, rate: int = 16000, margin_db: float = 6.0, start_frames: int = 5, end_silence: float = 0.3,
                 pad: float = 0.2, max_seconds: float = 10.0, floor_seconds: float = 5.0, min_speech: float = 0.2,
                 level_pct: float = 90.0, shape_pct: float = 90.0, shape_margin_db: float = 0.5,
                 resume_frames: int = 2, resume_after: float = 0.1):
        if rate != 16000:
            raise InvalidArgument(f"voice activity detection needs 16 kHz audio, not {rate} Hz")
        self.rate, self.hop = rate, rate // 100
        self.margin_db, self.start_frames = margin_db, start_frames
        self.resume_frames, self.resume_after = resume_frames, round(resume_after * 100)
        self.level_pct, self.shape_pct, self.shape_margin_db = level_pct, shape_pct, shape_margin_db
        self.end_frames, self.pad_frames = round(end_silence * 100), round(pad * 100)
        self.max_frames, self.min_frames = round(max_seconds * 100), round(min_speech * 100)
        n = round(floor_seconds * 100)
        self.history: deque[float] = deque(maxlen=n)  # frame levels (dB) outside utterances
        self.band_history: deque[np.ndarray] = deque(maxlen=n)  # their band spectra (dB)
        self.shape_history: deque[float] = deque(maxlen=n)  # their shape distance (dB)
        self.bands = BandSpectra()
        self._last_distance: float | None = None
        self._held: list[tuple[float, np.ndarray, float]] = []  # the current utterance's frames
        self.before: deque[tuple[np.ndarray, bool]] = deque(maxlen=self.pad_frames + start_frames)
        self.frames: list[np.ndarray] = []  # the utterance so far
        self.loud: list[bool] = []  # which of its frames were taken for speech
        self.loud_run = self.quiet_run = self.speech_frames = 0
        self.skipping = False  # the rest of an over-long sound
        self._rest = np.zeros(0, np.int16)
        self.heard_s = 0.0  # sound fed so far (s)
        self.cut_s: float | None = None  # heard_s when the last utterance was cut (its end of silence)
        self.started_s: float | None = None  # heard_s when the current (or last) utterance was taken to start

    @property
    def active(self) -> bool:
        return bool(self.frames) or self.skipping

    def learn_room_from(self, other: "VoiceActivity") -> None:
        """Take what another detector on the same microphone has learnt of the room's sound (until it has
        heard 30 frames of it, a detector takes nothing for speech: an owner's word then is learnt as noise)."""
        if len(other.history) > len(self.history):
            self.history = deque(other.history, maxlen=self.history.maxlen)
            self.band_history = deque(other.band_history, maxlen=self.band_history.maxlen)
            self.shape_history = deque(other.shape_history, maxlen=self.shape_history.maxlen)

    def relearn_room(self, pcm: np.ndarray) -> None:
        """Forget what was learnt of the room's sound and learn it from `pcm` (nobody speaking in it)
        instead: what the detector hears has changed (hearing/steering.py Steering's new filter), and
        sound judged against the old would differ from it in level and shape as a voice does."""
        n = len(pcm) // self.hop
        if n < 30:
            return
        frames = np.asarray(pcm[-n * self.hop:], np.int16).reshape(n, self.hop)
        db = frame_levels(frames)
        bands = BandSpectra().feed_frames(frames)
        shape = np.median(bands - bands.mean(axis=1, keepdims=True), axis=0)
        distance = _shape_distance(bands[1:], shape, float(_shape_distance(bands[:1], shape)[0]))
        self.history = deque(db, maxlen=self.history.maxlen)
        self.band_history = deque(bands, maxlen=self.band_history.maxlen)
        self.shape_history = deque(distance, maxlen=self.shape_history.maxlen)
        self._last_distance = None

    def reset(self) -> None:
        """Forget any utterance in progress (the robot itself spoke meanwhile)."""
        self.frames, self.loud, self.skipping = [], [], False
        self.before.clear()
        self.loud_run = self.quiet_run = self.speech_frames = 0

    def _learn(self, frames: Iterable[tuple[float, np.ndarray, float]]) -> None:
        for db, bands, d in frames:
            self.history.append(db)
            self.band_history.append(bands)
            if not math.isnan(d):
                self.shape_history.append(d)

    def _thresholds(self) -> tuple[float, np.ndarray, float] | None:
        """(level threshold dB, noise band shape, shape threshold dB) from the recent non-speech frames."""
        if len(self.history) < 30:
            return None
        level = float(np.percentile(self.history, self.level_pct)) + self.margin_db
        bands = np.asarray(self.band_history)
        shape = np.median(bands - bands.mean(axis=1, keepdims=True), axis=0)
        if len(self.shape_history) >= 30:
            limit = float(np.percentile(self.shape_history, self.shape_pct)) + self.shape_margin_db
        else:
            limit = math.inf
        return level, shape, limit

    def feed(self, pcm: np.ndarray) -> list["HeardUtterance"]:
        x = np.concatenate([self._rest, np.asarray(pcm, np.int16)])
        heard_before = self.heard_s - len(self._rest) / self.rate
        self.heard_s += len(pcm) / self.rate
        n = len(x) // self.hop
        self._rest = x[n * self.hop:]
        out: list[HeardUtterance] = []
        if n == 0:
            return out
        frames = x[:n * self.hop].reshape(n, self.hop)
        energies = frame_levels(frames)
        bands = self.bands.feed_frames(frames)
        limits = self._thresholds()  # once per chunk: the noise changes slowly
        if limits is not None:
            level, shape, shape_limit = limits
            distance = _shape_distance(bands, shape, self._last_distance)
            self._last_distance = float(distance[-1])
        for i, (frame, db) in enumerate(zip(frames, energies)):
            loud = False
            d = math.nan
            if limits is not None:
                d = float(distance[i])
                loud = db > level or d > shape_limit
            noise = (float(db), bands[i], d)
            if not self.frames:  # the room's own sound (an over-long one too): what utterances are judged against
                self._learn([noise])
            else:
                self._held.append(noise)
            was_active = self.active
            got = self._step(frame, loud)
            if self.frames and not was_active:
                self.started_s = heard_before + (i + 1) * self.hop / self.rate
            if not self.frames:
                if got is not None and got.too_long:  # a TV switched on, not a command: it is the room now
                    self._learn(self._held)
                self._held = []
            if got is not None:
                out.append(got)
                self.cut_s = heard_before + (i + 1) * self.hop / self.rate
                # its trailing silence beyond the pad is not part of it
                kept_silence = 0 if got.too_long else (self.end_frames - self.pad_frames) * self.hop
                got.end_sample = round(self.cut_s * self.rate) - kept_silence
        return out

    def _step(self, frame: np.ndarray, loud: bool) -> "HeardUtterance | None":
        if self.skipping:
            self.quiet_run = 0 if loud else self.quiet_run + 1
            if self.quiet_run >= self.end_frames:
                self.reset()
            return None
        if not self.frames:
            self.before.append((frame, loud))
            self.loud_run = self.loud_run + 1 if loud else 0
            if self.loud_run >= self.start_frames:
                self.frames, self.loud = [f for f, _ in self.before], [f for _, f in self.before]
                self.speech_frames, self.quiet_run = self.loud_run, 0
                self.before.clear()
            return None
        self.frames.append(frame)
        self.loud.append(loud)
        self.speech_frames += loud
        # a silence of `resume_after` ends only with `resume_frames` loud in a row (one alone is the
        # room's noise); a shorter one with any (a weak voice's frames in a TV are loud one in two)
        if loud and (self.quiet_run < self.resume_after or all(self.loud[-self.resume_frames:])):
            self.quiet_run = 0
        else:
            self.quiet_run += 1
        if len(self.frames) >= self.max_frames:
            got = HeardUtterance(np.concatenate(self.frames), self.speech_frames / 100, too_long=True,
                                 loud=np.array(self.loud))
            self.frames, self.loud, self.skipping, self.quiet_run = [], [], True, 0
            return got
        if self.quiet_run >= self.end_frames:
            got = self._padded()
            self.reset()
            return got if got.speech_seconds >= self.min_frames / 100 else None
        return None

    def _padded(self) -> "HeardUtterance":
        """The utterance so far, `pad` s of its silence kept (a lone loud frame in the silence left
        out is not its speech: the cut then equals what `ending` said before it)."""
        keep = len(self.frames) - self.quiet_run + self.pad_frames
        speech = self.speech_frames - sum(self.loud[keep:])
        return HeardUtterance(np.concatenate(self.frames[:keep]), speech / 100, loud=np.array(self.loud[:keep]))

    def ending(self) -> "HeardUtterance | None":
        """The utterance this detector will cut unless speech comes again, as soon as it is known: after
        `pad` s of silence its audio is fixed, and the rest of `end_silence` only confirms the end. A
        listener may start on it meanwhile (the Core spots a keyword in it): the cut, if it comes, is
        equal to it (pcm, loud, speech, end_sample). None while speech goes on or when it would not count."""
        if self.skipping or not self.frames or self.quiet_run < self.pad_frames:
            return None
        got = self._padded()
        if got.speech_seconds < self.min_frames / 100:
            return None
        fed = round(self.heard_s * self.rate) - len(self._rest)  # samples up to the last frame judged
        got.end_sample = fed - (self.quiet_run - self.pad_frames) * self.hop
        return got


def _shape_distance(bands: np.ndarray, shape: np.ndarray, before: float | None = None) -> np.ndarray:
    """How far each frame's band spectrum (level removed) departs from the room's usual `shape` (dB),
    each averaged with the frame's before (`before`: the distance of the one before the first; None:
    not averaged): one odd frame is no voice."""
    rel = bands - bands.mean(axis=1, keepdims=True) - shape
    distance: np.ndarray = np.sqrt(np.mean((rel - rel.mean(axis=1, keepdims=True)) ** 2, axis=1))
    if before is None:
        return distance
    averaged: np.ndarray = np.convolve(np.concatenate([[before], distance]), [0.5, 0.5], "valid")
    return averaged


@dataclass
class HeardUtterance:
    """A stretch of speech the microphone heard: int16 samples at 16 kHz."""

    pcm: np.ndarray
    speech_seconds: float  # loud frames in it
    too_long: bool = False
    bearing: float | None = None  # radians, robot's frame: where a microphone array heard it from
    end_sample: int = 0  # samples fed to its detector up to its last one (a Steering's: DELAY after the microphones')
    loud: np.ndarray | None = None  # per 10 ms of pcm: whether the detector took it for speech

    @property
    def seconds(self) -> float:
        return len(self.pcm) / 16000

    def then(self, more: "HeardUtterance") -> "HeardUtterance":
        """This utterance and the next as one: a sentence the detector cut where the speaker paused
        (each keeps its padding, so the pause stays about as long as it was)."""
        loud = None if self.loud is None or more.loud is None else np.concatenate([self.loud, more.loud])
        return HeardUtterance(np.concatenate([self.pcm, more.pcm]), self.speech_seconds + more.speech_seconds,
                              self.too_long or more.too_long, end_sample=more.end_sample, loud=loud)

