"""pocketsphinx with the US English model its wheel ships: a grammar of phrases decoded on 16 kHz
int16 audio and checked against a free phone loop.

    dec = PhraseDecoder(["check the hazards", "hazards"])    # words outside the dictionary: pronounce.py
    heard, margin = dec.decode(pcm, accept=0.0)              # phrase or None, log-score per second
    dec.segments                                             # (word, first, last 10 ms frame)
    PhraseDecoder(phrases, suffix=Suffix(jsgf, whole))       # each phrase may end with <suffix>'s words

Decoders are not thread-safe: one per thread. Each decode starts from a fresh front end
(fresh_front_end), so a kept decoder's answer depends on its own audio only.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from .errors import InvalidArgument


def fresh_front_end(decoder: Any) -> None:
    """Forget what the front end learnt of earlier utterances: its noise estimate (the model's
    `remove_noise`) carries over from one utterance to the next, so a kept decoder's answer depended
    on the audio it had decoded before (docs/sound.md, "Decoders"). After this, an answer depends on
    its own audio only, and a decoder can be kept (~75 ms to make)."""
    decoder.reinit_feat()


def sphinx_config(**kw: Any) -> Any:
    """A pocketsphinx configuration of the bundled US English model (no search yet)."""
    from pocketsphinx import Config, get_model_path
    return Config(hmm=get_model_path("en-us/en-us"), dict=get_model_path("en-us/cmudict-en-us.dict"),
                  samprate=16000, lm=None, loglevel="FATAL", **kw)


@dataclass(frozen=True)
class Suffix:
    """Words any phrase may end with (a time said after a command: agents/services/interpretation.py).
    `jsgf`: the JSGF rule `<suffix>` and the rules it names; `whole(words)`: whether the words heard
    after a phrase are a whole suffix (the search's best path may stop inside one: "every day at")."""

    jsgf: str
    whole: Callable[[str], bool]


class PhraseDecoder:
    """pocketsphinx on 16 kHz int16 audio: a JSGF grammar of phrases, checked against a free phone loop
    (a phrase is accepted only when its path scores at least as well as any phone sequence: the
    owner said one of the phrases, not something else). Not thread-safe: one per thread or call.
    Each `decode` starts from a fresh front end, so its answer depends on that audio alone."""

    def __init__(self, phrases: list[str] | None = None, jsgf: str | None = None, trust_search: bool = False,
                 words: Sequence[str] = (), beams: dict[str, float] | None = None, suffix: Suffix | None = None):
        from pocketsphinx import Decoder, get_model_path
        self.decoder = Decoder(sphinx_config(**(beams or {})))  # beams: e.g. WIDE_BEAMS
        # trust_search: the search's own best path, when a complete phrase, is the answer (see decode)
        self.trust_search = trust_search
        self.unknown: list[str] = []
        # words of the phrases (or of `words`, for a grammar's) missing from the dictionary, pronounced
        # by hearing/pronounce.py; those it cannot pronounce are listed in `unpronounced`
        self.added, self.unpronounced = self._pronounce(list(phrases or []) + list(words))
        if jsgf is None:
            known = [p for p in dict.fromkeys(normalize(p) for p in phrases or []) if p and self.known(p)]
            self.unknown = [p for p in phrases or [] if normalize(p) not in known]
            self.phrases = known
            jsgf = grammar(known, suffix=suffix) if known else None
        else:
            self.phrases = []
        self.suffix = suffix
        self.has_grammar = jsgf is not None
        self._single: dict[str, str] = {}  # phrase -> the search of a grammar of it alone (least recent first)
        self._made = 0
        if jsgf is not None:
            try:
                self.decoder.add_jsgf_string("phrases", jsgf)
            except (RuntimeError, ValueError) as e:
                raise InvalidArgument(f"bad JSGF grammar: {e}") from None
        self.decoder.add_allphone_file("phones", get_model_path("en-us/en-us-phone.lm.bin"))

    # wider than pocketsphinx's defaults (1e-48, 7e-29, 1e-48): with those, the Platform's search of
    # the Store's sentences pruned the one said and reached no sentence's end. Narrower did not reach
    # it with one microphone; the Core's keyword spotter keeps the defaults, where wider moved as many
    # keywords each way. Its cost per room: docs/sound.md, "Decoders"
    WIDE_BEAMS = dict(beam=1e-80, wbeam=1e-60, pbeam=1e-80)

    def known(self, phrase: str) -> bool:
        return all(self.decoder.lookup_word(w) for w in phrase.split())

    MAX_ADDED = 500  # words pronounced for one decoder (~2 ms each: eSpeak NG is loaded per word)

    def _pronounce(self, phrases: list[str]) -> tuple[list[str], list[str]]:
        """Give the dictionary the phrases' words it lacks: (added, without a pronunciation)."""
        from .pronounce import pronunciation
        missing = [w for w in dict.fromkeys(w for p in phrases for w in normalize(p).split())
                   if not self.decoder.lookup_word(w)]
        added: list[str] = []
        failed: list[str] = []
        for w in missing:
            phones = pronunciation(w) if len(added) < self.MAX_ADDED else None
            if phones is None:
                failed.append(w)
                continue
            self.decoder.add_word(w, phones, False)
            added.append(w)
        return added, failed

    def _run(self, search: str, pcm: np.ndarray) -> Any:
        d = self.decoder
        d.activate_search(search)
        d.start_utt()
        d.process_raw(np.asarray(pcm, "<i2").tobytes(), False, True)
        d.end_utt()
        return d.hyp()

    def decode(self, pcm: np.ndarray, accept: float = 0.0) -> tuple[str | None, float]:
        """(phrase heard or None, margin: how much better the phrase's path scores than the phone loop's,
        log-score per second; >= `accept` accepts). `segments` then holds (word, first, last 10 ms frame).

        pocketsphinx's grammar search ends wherever the best path is, often inside a phrase (a prefix
        such as "read" of "read my e-mail" outscores the keyword "quiz" that was said). Then the answer
        is the best *complete* phrase among the search's N-best, aligned alone to the audio (its score
        then depends on that phrase only). With `trust_search`, when the search's best path is a
        complete phrase, it is the answer: aligned alone, a longer phrase can outscore the short one
        said (the cognitive game's "six", in a grammar of the numbers 0-300, lost to "thirty five" in 2
        of 8 recordings); the runner-up then only sets the lead. (The Core's keywords keep the best
        aligned phrase: measured on the speech benchmark that way.) The answer's aligned score is
        compared with the free phone loop: the owner said the phrase, not something else."""
        self.segments: list[tuple[str, int, int]] = []
        self.lead, self.runner_up = math.inf, None
        if not self.has_grammar:
            return None, 0.0
        fresh_front_end(self.decoder)
        candidates = self._complete_phrases(pcm)
        if not candidates:
            return None, -math.inf
        aligned = sorted((a for a in map(lambda w: self._align(w, pcm), candidates) if a is not None),
                         key=lambda a: -a[1])
        if not aligned:
            return None, -math.inf
        first = next((a for a in aligned if a[0] == candidates[0]), None)
        if self.trust_search and self._best_path_complete and first is not None:
            aligned.remove(first)
            aligned.insert(0, first)  # the search's own complete answer (its lead over the runner-up may be < 0)
        words, score, self.segments = aligned[0]
        seconds = max(len(pcm) / 16000, 0.1)
        # how clearly the phrase beats the runner-up (log-score per second; inf: no other complete phrase)
        self.lead = (score - aligned[1][1]) / seconds if len(aligned) > 1 else math.inf
        self.runner_up = aligned[1][0] if len(aligned) > 1 else None
        loop = self._run("phones", pcm)
        margin = (score - math.log(max(loop.score if loop else 0.0, 1e-300))) / seconds
        return (words if margin >= accept else None), float(margin)

    KEPT_SINGLE = 64  # grammars of one phrase kept for _align
    NBEST = 40  # lattice paths looked through for complete phrases
    CANDIDATES = 2  # complete phrases aligned (~15 ms each)

    def _complete_phrases(self, pcm: np.ndarray) -> list[str]:
        hyp = self._run("phrases", pcm)
        self._best_path_complete = False
        if hyp is None:
            return []
        out: list[str] = []
        first = [hyp.hypstr.strip()]
        try:
            more = [nb.hypstr.strip() for nb, _ in zip(self.decoder.nbest(), range(self.NBEST)) if nb is not None]
        except (RuntimeError, TypeError):  # no lattice (nothing decoded)
            more = []
        for words in first + more:
            if words and self._whole(words) and words not in out:
                out.append(words)
                if len(out) >= self.CANDIDATES:
                    break
        self._best_path_complete = bool(out) and out[0] == first[0]
        return out

    def _whole(self, words: str) -> bool:
        """A path through the whole grammar: one of the phrases, or one and a whole suffix."""
        if not self.phrases or words in self.phrases:
            return True
        return self.suffix is not None and any(
            words.startswith(p + " ") and self.suffix.whole(words[len(p) + 1:]) for p in self.phrases)

    def _align(self, words: str, pcm: np.ndarray) -> tuple[str, float, list[tuple[str, int, int]]] | None:
        """(words, log-score, segments) of a grammar of `words` alone on the audio (the same search as the
        phrases', so its score compares with the phone loop's as before), or None where the search
        does not reach the phrase's end."""
        d = self.decoder
        search = self._single.pop(words, None)
        if search is None:
            self._made += 1
            search = f"one{self._made}"
            d.add_jsgf_string(search, grammar([words]))
        self._single[words] = search
        if len(self._single) > self.KEPT_SINGLE:  # a kept decoder of a word loop meets ever new phrases
            d.remove_search(self._single.pop(next(iter(self._single))))
        hyp = self._run(search, pcm)
        if hyp is None or hyp.hypstr.strip() != words:
            return None
        segments = [(s.word, s.start_frame, s.end_frame) for s in d.seg()]
        return words, math.log(max(hyp.score, 1e-300)), segments


def normalize(phrase: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"[^\w\s']", " ", phrase.lower())).strip()


def grammar(phrases: list[str], repeat: bool = False, suffix: Suffix | None = None) -> str:
    """A JSGF grammar: one of the phrases (repeat: any sequence of them; suffix: each may end with it)."""
    body = " | ".join(f"({p})" for p in phrases)
    rule = f"( {body} )+" if repeat else f"( {body} ) [<suffix>]" if suffix else body
    rules = f"{suffix.jsgf.strip()}\n" if suffix else ""
    return f"#JSGF V1.0;\ngrammar phrases;\npublic <phrase> = {rule};\n{rules}"
