"""Text to speech with eSpeak NG: the library and voice data bundled by the espeakng-loader wheel,
called through ctypes (the package only tells where the library is).

    pcm = synthesize("check the hazards", voice="en-us+f3", rate=140)   # int16, 16 kHz mono

eSpeak NG keeps one global synthesizer per process, so calls are serialised by a lock, and each call
loads the library afresh (the same text, voice and rate give the same samples whatever came before);
a call takes a few milliseconds per second of speech, still CPU work: async callers run it in an
executor.
eSpeak NG is GPL-3.0-or-later; it is loaded as a separate shared library at run time, never shipped
in this repository."""
from __future__ import annotations

import _ctypes
import contextlib
import ctypes
import threading
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from scipy.signal import resample_poly

from .errors import InvalidArgument, SpeechUnavailable
from .wav import SAMPLE_RATE

DEFAULT_VOICE = "en-us"
# voices the tests and measurements use; any eSpeak NG voice name with an optional "+variant" works
VOICES = ("en-us", "en-us+f3", "en-us+m3", "en-us+klatt", "en", "en+f2")
LANGUAGE_VOICES = {"en": "en-us", "en-us": "en-us", "en-gb": "en"}
RATE_RANGE = (80, 450)  # words per minute eSpeak NG accepts
DEFAULT_RATE = 160
MAX_TEXT = 2000  # characters in one call

_AUDIO_OUTPUT_SYNCHRONOUS = 2
_CHARS_UTF8 = 1
_RATE, _PITCH = 1, 3  # espeak_PARAMETER
_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int, ctypes.c_void_p)
_lock = threading.Lock()
RAND_SEED = 1  # eSpeak's and libc's random generators, at every synthesis (breath noise)
_LIBC = ctypes.CDLL(None)  # this process's own symbols, the C library's srand among them
_chunks: list[np.ndarray] = []


def _on_samples(wav: Any, n: int, events: Any) -> int:  # called by espeak_Synth, in the calling thread, under _lock
    if n > 0:
        _chunks.append(np.ctypeslib.as_array(wav, (n,)).copy())
    return 0


_collect = _CALLBACK(_on_samples)


@contextlib.contextmanager
def _fresh_engine() -> Iterator[tuple[ctypes.CDLL, int]]:
    """The library loaded afresh for one synthesis, under the lock, and unloaded after it: eSpeak NG's
    wave generator keeps state in static variables that espeak_Terminate does not reset, so a text's
    samples would depend on the syntheses before it; two first calls must not initialise at once
    (what was seen and what a load costs: docs/sound.md, "Decoders")."""
    try:
        import espeakng_loader
    except ImportError:
        raise SpeechUnavailable("text to speech needs the espeakng-loader package (pip install espeakng-loader)") \
            from None
    with _lock:
        lib = ctypes.CDLL(espeakng_loader.get_library_path())
        try:
            lib.espeak_Initialize.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_char_p, ctypes.c_int]
            lib.espeak_SetVoiceByName.argtypes = [ctypes.c_char_p]
            lib.espeak_SetParameter.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int]
            lib.espeak_Synth.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint, ctypes.c_int,
                                         ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p]
            lib.espeak_SetSynthCallback.argtypes = [_CALLBACK]
            rate = lib.espeak_Initialize(_AUDIO_OUTPUT_SYNCHRONOUS, 0, espeakng_loader.get_data_path().encode(), 0)
            if rate <= 0:
                raise SpeechUnavailable(f"eSpeak NG failed to initialise (code {rate})")
            lib.espeak_SetSynthCallback(_collect)
            # a voice's breath noise (the "+f2" variants) draws on eSpeak's own generator and libc's
            # rand(), seeded from the clock: both fixed, so the noise is the same at every call
            lib.espeak_ng_SetRandSeed.argtypes = [ctypes.c_long]
            lib.espeak_ng_SetRandSeed(RAND_SEED)
            _LIBC.srand(RAND_SEED)
            try:
                yield lib, rate
            finally:
                lib.espeak_Terminate()
        finally:
            handle = lib._handle  # noqa: SLF001 - ctypes keeps no public way to unload
            del lib
            _ctypes.dlclose(handle)  # the last reference: the next load starts from the file's state


def _set_voice(lib: ctypes.CDLL, voice: str) -> None:
    if lib.espeak_SetVoiceByName(voice.encode()) != 0:
        raise InvalidArgument(f"unknown voice {voice!r} (e.g. {', '.join(VOICES)})")


def check_voice(voice: str) -> None:
    """InvalidArgument where eSpeak NG has no such voice (SpeechUnavailable: no eSpeak NG)."""
    with _fresh_engine() as (lib, _):
        _set_voice(lib, voice)


_IPA, _SEPARATOR = 0x02, ord("_") << 8  # espeak_TextToPhonemes: IPA, phonemes joined by "_"


def phonemes(text: str, voice: str = DEFAULT_VOICE) -> list[str]:
    """How eSpeak NG would say `text` in `voice`: its phonemes in IPA, one string per word group, the
    phonemes separated by "_" and carrying stress marks (e.g. "greeter" -> ["ɡ_ɹ_ˈiː_ɾ_ɚ"])."""
    if not text.strip() or len(text) > MAX_TEXT:
        raise InvalidArgument(f"no phonemes for a text of {len(text)} characters")
    with _fresh_engine() as (lib, _):
        _set_voice(lib, voice)
        lib.espeak_TextToPhonemes.restype = ctypes.c_char_p
        lib.espeak_TextToPhonemes.argtypes = [ctypes.POINTER(ctypes.c_char_p), ctypes.c_int, ctypes.c_int]
        rest = ctypes.c_char_p(text.encode())  # the call moves it on, clause by clause, to NULL
        out: list[str] = []
        while rest.value:
            got = lib.espeak_TextToPhonemes(ctypes.byref(rest), _CHARS_UTF8, _IPA | _SEPARATOR)
            out.extend((got or b"").decode(errors="replace").split())
        return out


def data_path() -> Path:
    import espeakng_loader
    return Path(espeakng_loader.get_data_path())


def voice_for(language: str, voice: str = "") -> str:
    """The voice to use: `voice` when given, else the default voice of `language`."""
    if voice:
        return voice
    try:
        return LANGUAGE_VOICES[language.lower()]
    except KeyError:
        raise InvalidArgument(f"no voice for language {language!r} (known: {', '.join(LANGUAGE_VOICES)})") from None


def synthesize(text: str, voice: str = DEFAULT_VOICE, rate: int = DEFAULT_RATE, pitch: int = 50) -> np.ndarray:
    """Speech for `text`: int16 samples at 16 kHz (eSpeak's 22.05 kHz resampled)."""
    if not text.strip():
        raise InvalidArgument("nothing to say: the text is empty")
    if len(text) > MAX_TEXT:
        raise InvalidArgument(f"text of {len(text)} characters exceeds {MAX_TEXT}")
    if not RATE_RANGE[0] <= rate <= RATE_RANGE[1]:
        raise InvalidArgument(f"speech rate {rate} words/min out of range {RATE_RANGE[0]}..{RATE_RANGE[1]}")
    if not 0 <= pitch <= 99:
        raise InvalidArgument(f"pitch {pitch} out of range 0..99")
    data = text.encode() + b"\0"
    with _fresh_engine() as (lib, native):
        _set_voice(lib, voice)
        lib.espeak_SetParameter(_RATE, int(rate), 0)
        lib.espeak_SetParameter(_PITCH, int(pitch), 0)
        _chunks.clear()
        err = lib.espeak_Synth(data, len(data), 0, 0, 0, _CHARS_UTF8, None, None)
        pcm = np.concatenate(_chunks) if _chunks else np.zeros(0, np.int16)
        _chunks.clear()
    if err != 0:
        raise InvalidArgument(f"eSpeak NG could not synthesise the text (code {err})")
    g = np.gcd(SAMPLE_RATE, native)
    out = resample_poly(pcm.astype(np.float64), SAMPLE_RATE // g, native // g)
    speech: np.ndarray = np.clip(np.round(out), -32768, 32767).astype(np.int16)
    return speech
