"""Speech recognition (pocketsphinx, the US English model its wheel ships), text to speech (eSpeak NG)
and noise profiles (spectral subtraction, as the original Platform's denoising before Sphinx).

Garbage is refused with a reason: not a WAV (malformed), not mono 16-bit 16 kHz (unsupported),
longer than MAX_SECONDS (too-large, judged from the header alone), silent or clipped (invalid)."""
from __future__ import annotations

import base64
import math
import threading
from collections import OrderedDict

import numpy as np
from scipy.signal import istft, stft

from ontology.errors import ErrorCode
from ontology.services.speech import (NoiseProfile, Recognition, RecognizedWord, Speech, SpeechNoiseProfile,
                                      SpeechRecognition, TextToSpeech)
from hearing import tts
from hearing.decoder import PhraseDecoder, Suffix, fresh_front_end, grammar, normalize, sphinx_config
from hearing.errors import HearingError
from hearing.vad import speech_segments
from hearing.wav import SAMPLE_RATE, decode_wav, encode_wav, level_dbfs

from .context import ServiceContext
from .errors import ServiceError
from .interpretation import SLOT  # the slots interpret_command fills from the text heard
from .interpretation import SAID_TIMES_JSGF, SCHEDULE_SENTENCES, said_time
from .interpretation import normalize as said_as  # how a slot value (a room name) is said

MAX_SECONDS = 30.0
SILENT_DBFS = -70.0  # peak: below a microphone's own noise, nothing was recorded at all
CLIPPED_FRACTION = 0.005  # more samples than this at full scale: the level was too high to recognise
NPERSEG = 512  # 32 ms frames for the noise spectrum
OVERSUBTRACT, FLOOR = 1.0, 0.1  # spectral subtraction: alpha, floor beta (more alpha hurt the words)
LANGUAGES = ("en", "en-us")


def _audio(b64: str) -> np.ndarray:
    try:
        data = base64.b64decode(b64, validate=True)
    except ValueError:
        raise ServiceError("audio_b64 is not base64", ErrorCode.MALFORMED) from None
    try:
        pcm, _ = decode_wav(data, rates=(SAMPLE_RATE,), max_seconds=MAX_SECONDS)
    except HearingError as e:
        raise ServiceError(e.message, e.code) from None
    if pcm.size < SAMPLE_RATE // 10:
        raise ServiceError(f"recording of {pcm.size / SAMPLE_RATE:.2f} s is too short", ErrorCode.INVALID)
    return pcm


def _check_level(pcm: np.ndarray) -> None:
    _, peak = level_dbfs(pcm)
    if peak < SILENT_DBFS:
        raise ServiceError(f"the recording is silent (peak {peak:.0f} dBFS)", ErrorCode.INVALID)
    clipped = float(np.mean(np.abs(pcm.astype(np.int32)) >= 32767))
    if clipped > CLIPPED_FRACTION:
        raise ServiceError(f"the recording is clipped ({100 * clipped:.1f}% of samples at full scale): "
                           "lower the gain or speak further from the microphone", ErrorCode.INVALID)


# ------------------------------------------------------------------------------------------ noise
def _profiles(ctx: ServiceContext) -> dict:
    return ctx.state.store("speech_noise_profiles", dict)


def noise_profile(req: SpeechNoiseProfile, ctx: ServiceContext) -> NoiseProfile:
    pcm = _audio(req.audio_b64)
    if level_dbfs(pcm)[1] >= -1.0:
        raise ServiceError("the noise recording is clipped", ErrorCode.INVALID)
    _, _, spec = stft(pcm.astype(np.float64), nperseg=NPERSEG)
    _profiles(ctx)[(ctx.user, req.name)] = np.mean(np.abs(spec) ** 2, axis=1)
    return NoiseProfile(name=req.name, noise_dbfs=level_dbfs(pcm)[0])


def subtract_noise(pcm: np.ndarray, noise_power: np.ndarray) -> np.ndarray:
    """Spectral subtraction: |X|^2 - alpha * N, floored at beta * N, with the noisy phase."""
    _, _, spec = stft(pcm.astype(np.float64), nperseg=NPERSEG)
    power = np.abs(spec) ** 2
    clean = np.maximum(power - OVERSUBTRACT * noise_power[:, None], FLOOR * noise_power[:, None])
    _, out = istft(np.sqrt(clean) * np.exp(1j * np.angle(spec)), nperseg=NPERSEG)
    return np.clip(np.round(out[:len(pcm)]), -32768, 32767).astype(np.int16)


# ------------------------------------------------------------------------------------------ recognition
# decoders are kept per worker thread (pocketsphinx is not thread-safe; making one takes 75 ms, the
# general language model's ~1 s) and start each utterance from a fresh front end (fresh_front_end),
# so an answer never depends on other requests' audio
_kept = threading.local()
KEPT_GRAMMARS = 2  # phrase decoders kept per thread (~28 MB each: the acoustic model), least recent dropped


def _language_model_decode(pcm: np.ndarray) -> tuple[str, float, list]:
    dec = getattr(_kept, "lm", None)
    if dec is None:
        from pocketsphinx import Decoder, get_model_path
        dec = Decoder(sphinx_config())
        dec.add_lm_file("lm", get_model_path("en-us/en-us.lm.bin"))
        dec.activate_search("lm")
        _kept.lm = dec
    fresh_front_end(dec)
    dec.start_utt()
    dec.process_raw(pcm.tobytes(), False, True)
    dec.end_utt()
    hyp = dec.hyp()
    lm = dec.get_logmath()
    segs = [(s.word, lm.exp(s.prob), s.start_frame, s.end_frame) for s in dec.seg()]
    return (hyp.hypstr if hyp else ""), (hyp.prob if hyp else 0.0), segs


def _words(segs) -> list[RecognizedWord]:
    out = []
    for word, conf, s, e in segs:
        if word.startswith(("<", "[")) or word == "<sil>":
            continue  # silences and fillers
        out.append(RecognizedWord(word=word.split("(")[0], confidence=round(float(min(max(conf, 0.0), 1.0)), 3),
                                  start=s / 100, end=(e + 1) / 100))
    return out


def speech_recognition(req: SpeechRecognition, ctx: ServiceContext) -> Recognition:
    if req.language.lower() not in LANGUAGES:
        raise ServiceError(f"language {req.language!r} not available (known: {', '.join(LANGUAGES)})",
                           ErrorCode.UNSUPPORTED)
    pcm = _audio(req.audio_b64)
    _check_level(pcm)
    if req.noise_profile:
        profile = _profiles(ctx).get((ctx.user, req.noise_profile))
        if profile is None:
            raise ServiceError(f"no noise profile {req.noise_profile!r} (store one with speech_noise_profile)",
                               ErrorCode.NOT_FOUND)
        pcm = subtract_noise(pcm, profile)
    if not (req.grammar or req.sentences or req.words):
        if not speech_segments(pcm):  # the language model would make words of any noise
            return Recognition(text="", search="language_model")
        text, prob, segs = _language_model_decode(pcm)
        return Recognition(text=text, words=_words(segs), confidence=round(float(prob), 3), search="language_model")
    try:
        if req.grammar:
            dec, search = _phrase_decoder(("jsgf", req.grammar)), "grammar"
        elif req.sentences:
            sentences = with_slots_filled(req.sentences, _slot_values(req, ctx))
            if not sentences:  # only sentences with slots of no known value: nothing to search
                return Recognition(text="", search="sentences")
            if req.times:  # a schedule said: the sentences, each with an optional time, and the schedules' own
                sentences = list(dict.fromkeys(sentences + SCHEDULE_SENTENCES))
            dec, search = _phrase_decoder(("sentences+times" if req.times else "sentences", *sentences)), "sentences"
        else:
            phrases = [p for p in (normalize(w) for w in req.words) if p]
            dec, search = _phrase_decoder(("jsgf", grammar(phrases, repeat=True)), phrases), "words"
    except HearingError as e:
        raise ServiceError(e.message, ErrorCode.INVALID) from None
    if search == "sentences" and not dec.phrases:
        raise ServiceError(f"no sentence has only words the recogniser can pronounce: {req.sentences[:3]} "
                           f"(without a pronunciation: {', '.join(dec.unpronounced[:5])}; words outside its "
                           "dictionary are pronounced by eSpeak NG: the speech extra)", ErrorCode.UNSUPPORTED)
    heard, margin = dec.decode(pcm, accept=SENTENCES_ACCEPT if search == "sentences" else 0.0)
    if heard is not None and req.times and heard not in dec.phrases and margin < SCHEDULE_ACCEPT:
        heard = None  # a time after a sentence, fitting only loosely: more often other words (docs/sound.md)
    if heard is None:
        return Recognition(text="", search=search, confidence=_confidence(margin))
    conf = _confidence(margin)
    return Recognition(text=heard, words=_words([(w, conf, s, e) for w, s, e in dec.segments]), confidence=conf,
                       search=search)


SAID_TIMES = Suffix(SAID_TIMES_JSGF, said_time)  # a schedule's time after a sentence (`times`)
MAX_FILLED = 2000  # sentences after the slots are filled (a grammar of them builds in ~0.1 s)


def needs_rooms(req: SpeechRecognition) -> bool:
    """Whether a sentence holds a {room} the request gives no values for: the caller's homes fill it
    (agents/services/pool.py takes them along to a worker)."""
    return "room" not in req.slots and any("room" in SLOT.findall(s) for s in req.sentences)


def _slot_values(req: SpeechRecognition, ctx: ServiceContext) -> dict[str, list[str]]:
    values = dict(req.slots)
    if needs_rooms(req):
        from .home import homes
        values["room"] = homes(ctx.state).rooms(ctx.user)
    # as they are said: a home's "living_room" is heard "living room" (interpret_command maps it back)
    return {k: list(dict.fromkeys(said_as(v) for v in vs if said_as(v))) for k, vs in values.items()}


def with_slots_filled(sentences: list[str], values: dict[str, list[str]]) -> list[str]:
    """Each sentence once per combination of its slots' values ("check the lamps in the {room}" ->
    "... in the kitchen", "... in the hall"); a sentence with a slot of no value is left out."""
    out: list[str] = []
    for sentence in sentences:
        names = SLOT.findall(sentence)
        if any(not values.get(n) for n in names):
            continue
        filled = [sentence]
        for name in dict.fromkeys(names):
            filled = [f.replace("{" + name + "}", v) for f in filled for v in values[name]]
            if len(out) + len(filled) > MAX_FILLED:
                raise ServiceError(f"the sentences' slots make more than {MAX_FILLED} sentences", ErrorCode.INVALID)
        out.extend(filled)
    return out


def _phrase_decoder(key: tuple, words: list[str] = ()) -> PhraseDecoder:
    """This thread's decoder of `key`'s grammar, made on first use (the Core sends the same Store
    phrases with every command, so most requests find theirs). `words`: a grammar's words, so those
    outside the dictionary are pronounced first."""
    kept: OrderedDict | None = getattr(_kept, "phrases", None)
    if kept is None:
        kept = _kept.phrases = OrderedDict()
    dec = kept.pop(key, None)
    if dec is None:
        # the Store's sentences searched wide (PhraseDecoder.WIDE_BEAMS); a grammar of words as before:
        # there the phone loop searched wide too gained as much as the words
        dec = PhraseDecoder(jsgf=key[1], words=words) if key[0] == "jsgf" else \
            PhraseDecoder(list(key[1:]), beams=PhraseDecoder.WIDE_BEAMS,
                          suffix=SAID_TIMES if key[0] == "sentences+times" else None)
    kept[key] = dec
    while len(kept) > KEPT_GRAMMARS:
        kept.popitem(last=False)
    return dec


# how far a sentence's path must score above the free phone loop (log-score per second) to be taken:
# at 0 other sentences said in a quiet room were taken for a command phrase, and this bound kept every
# command phrase 0 kept (docs/sound.md, "Keywords")
SENTENCES_ACCEPT = 0.02
# a sentence heard with a time after it (`times`) is taken from this margin on: other words after a
# command phrase ("... from my son") were forced into a time below it, schedules said were heard above
# it (docs/sound.md, "Schedules said aloud")
SCHEDULE_ACCEPT = 0.07
MARGIN_SCALE = 0.03  # margin (PhraseDecoder.decode) at which the confidence is 0.73


def _confidence(margin: float) -> float:
    """The phrase path's score against the free phone loop (PhraseDecoder.decode), mapped to 0..1."""
    if not math.isfinite(margin):
        return 0.0
    return round(1.0 / (1.0 + math.exp(-max(min(margin / MARGIN_SCALE, 50.0), -50.0))), 3)


# ------------------------------------------------------------------------------------------ synthesis
def text_to_speech(req: TextToSpeech, ctx: ServiceContext) -> Speech:
    try:
        pcm = tts.synthesize(req.text, tts.voice_for(req.language, req.voice), req.speed)
    except HearingError as e:
        raise ServiceError(e.message, e.code) from None
    return Speech(audio_b64=base64.b64encode(encode_wav(pcm)).decode(), sample_rate=SAMPLE_RATE,
                  seconds=len(pcm) / SAMPLE_RATE)
