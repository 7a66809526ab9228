"""Speech services: recognition (words, sentences or a JSGF grammar, or the general language model),
text to speech, and a room's noise profile subtracted before recognition (spectral subtraction).
Audio travels as base64 mono 16-bit PCM WAV at 16 kHz."""
from __future__ import annotations

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, action

GROUP = "speech"
MAX_WAV_B64 = 240_000  # ~5.5 s of 16 kHz audio: what one message carries (agents/base.py MAX_BODY)


class RecognizedWord(Content):
    word: str
    confidence: float  # 0..1
    start: float  # seconds from the start of the recording
    end: float


class Recognition(Content):
    text: str  # "" when nothing the request allows was said
    words: list[RecognizedWord] = []
    confidence: float = 0.0  # of the whole utterance, 0..1
    search: str  # "grammar", "sentences", "words" or "language_model"


@action("speech_recognition", ontology="platform", reply=Recognition, group=GROUP, idempotent=True)
class SpeechRecognition(ServiceRequest):
    """Recognise `audio_b64`: against `grammar` (JSGF), else one of `sentences`, else any sequence of
    `words`, else the general US English language model. `noise_profile` names a profile stored by
    speech_noise_profile to subtract first. A sentence may hold slots, as a RApp's phrases do
    ("check the lamps in the {room}"): `slots` gives the values each may take, and {room} defaults
    to the rooms of the caller's homes on the Platform; a sentence with a slot of no known value is
    left out (the general model may still hear it). `times`: each sentence may end with a time, as a
    schedule is said ("check the hazards every day at ten p m", "... in ten minutes"), and the
    schedules' own sentences are heard ("what is scheduled", "cancel the evening check")."""

    audio_b64: str = Field(min_length=1, max_length=MAX_WAV_B64)
    language: str = "en"
    words: list[str] = Field(default_factory=list, max_length=500)
    sentences: list[str] = Field(default_factory=list, max_length=500)
    grammar: str = Field(default="", max_length=20_000)
    noise_profile: str = ""
    slots: dict[str, list[str]] = Field(default_factory=dict, max_length=20)
    times: bool = False


class NoiseProfile(Content):
    name: str
    noise_dbfs: float  # the room's noise level in the recording


@action("speech_noise_profile", ontology="platform", reply=NoiseProfile, group=GROUP)
class SpeechNoiseProfile(ServiceRequest):
    """Store the spectrum of a recording of the room without speech under `name` (per user)."""

    audio_b64: str = Field(min_length=1, max_length=MAX_WAV_B64)
    name: str = Field(default="default", min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")


class Speech(Content):
    audio_b64: str  # WAV
    sample_rate: int
    seconds: float


@action("text_to_speech", ontology="platform", reply=Speech, group=GROUP, idempotent=True)
class TextToSpeech(ServiceRequest):
    """Synthesise `text` (eSpeak NG) as a WAV recording."""

    text: str = Field(min_length=1, max_length=400)
    language: str = "en"
    voice: str = ""
    speed: int = Field(default=160, ge=80, le=450)


__all__ = ["SpeechRecognition", "Recognition", "RecognizedWord", "SpeechNoiseProfile", "NoiseProfile",
           "TextToSpeech", "Speech"]
