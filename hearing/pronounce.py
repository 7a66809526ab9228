"""Pronunciations for words pocketsphinx's dictionary lacks ("greeter", "roomba", a RApp's made-up
name), so a RApp's keywords and phrases can be said whatever words they use.

eSpeak NG (hearing/tts.py `phonemes`) says how the word sounds, in IPA; that is mapped to the phones
of pocketsphinx's US English model (ARPAbet, as cmudict writes them):

    pronunciation("greeter")   # "G R IY T ER"; None where eSpeak NG is missing or a sound has no phone

Fidelity: in the simulation the owner's voice is eSpeak NG too, so a word pronounced this way
matches what the microphone hears exactly; a person may say it otherwise (stress, a flap for a "t").
"""
from __future__ import annotations

import functools
import re

from .errors import HearingError

# IPA (as eSpeak NG's en-us voice writes it) -> ARPAbet; longest match first within a phoneme
_PHONES = {
    "aɪɚ": "AY ER", "aʊɚ": "AW ER", "ɔːɹ": "AO R", "ɑːɹ": "AA R", "ɛɹ": "EH R", "ɪɹ": "IH R", "ʊɹ": "UH R",
    "aɪ": "AY", "aʊ": "AW", "ɔɪ": "OY", "eɪ": "EY", "oʊ": "OW", "əʊ": "OW", "tʃ": "CH", "dʒ": "JH",
    "iː": "IY", "uː": "UW", "ɑː": "AA", "ɔː": "AO", "ɜː": "ER", "əl": "AH L", "n̩": "AH N", "l̩": "AH L",
    "i": "IY", "ɪ": "IH", "ᵻ": "IH", "e": "EY", "ɛ": "EH", "æ": "AE", "a": "AE", "ɑ": "AA", "ɒ": "AA",
    "ɔ": "AO", "o": "OW", "ʊ": "UH", "u": "UW", "ʌ": "AH", "ə": "AH", "ɐ": "AH", "ɚ": "ER", "ɜ": "ER",
    "p": "P", "b": "B", "t": "T", "d": "D", "k": "K", "ɡ": "G", "g": "G", "f": "F", "v": "V", "θ": "TH",
    "ð": "DH", "s": "S", "z": "Z", "ʃ": "SH", "ʒ": "ZH", "h": "HH", "m": "M", "n": "N", "ŋ": "NG",
    "l": "L", "ɫ": "L", "ɹ": "R", "r": "R", "w": "W", "j": "Y", "x": "K",
    "ɾ": "T", "ʔ": "T",  # a flap and a glottal stop stand for a "t" (or "d") in American English
}
# one eSpeak phoneme, longest first; a length mark a vowel did not take is skipped; any other
# character is a sound without a phone
_TOKEN = re.compile("|".join(map(re.escape, sorted(_PHONES, key=len, reverse=True))) + "|(ː)|(.)")
_MARKS = str.maketrans("", "", "ˈˌ-")  # stress and eSpeak's own separators carry no phone


def ipa_to_phones(units: list[str]) -> str | None:
    """ARPAbet phones of eSpeak NG phoneme strings ("_"-separated), or None at a sound without one."""
    out: list[str] = []
    for phoneme in "_".join(units).translate(_MARKS).split("_"):  # matched within one phoneme only
        for m in _TOKEN.finditer(phoneme):
            if m.group(2) is not None:
                return None
            if m.group(1) is None:
                out.append(_PHONES[m.group(0)])
    return " ".join(out) or None


@functools.lru_cache(maxsize=4096)
def pronunciation(word: str, voice: str = "en-us") -> str | None:
    """The word's phones for pocketsphinx's US English model, or None (no eSpeak NG here, or a sound
    without a phone). Deterministic: eSpeak NG's phonemes depend on the text and voice only."""
    from . import tts
    try:
        units = tts.phonemes(word, voice)
    except HearingError:  # eSpeak NG missing (SpeechUnavailable) or the word refused
        return None
    return ipa_to_phones(units)
