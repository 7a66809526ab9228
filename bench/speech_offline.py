"""The speech path's recognisers alone, without agents: the same house, voices, distances and TV as
bench/speech.py, each recording cut by the Core's voice activity detector, then decided as the Core
and the Platform decide (KeywordSpotter for s4a; speech_recognition with the Store's phrases, then the
language model, then interpret_command for s4b). Minutes instead of the agent bench's six, and many
more recordings per cell, so a change to a recogniser is judged on more than 10 commands a cell.

    python -m bench.speech_offline [--quick] [--only platform|keyword] [--show-wrong] [--rt60 S]

Three more keyword paths, measured on request (--only): `supervision`, the Core's supervision words
("stop", "cancel", "resume", ...) said alone, spotted as the Core spots them during a task, and
everything else the owner says, which must not be taken for one; `words`, the cognitive game's
answers said alone, found as the robot's word_spotting finds them (robots/microphones.py
spot_in_audio: the recording cut by level, each piece decoded with the game's words), and the
other sentences; `confirm`, the owner's yes or no to the Core's question before it keeps a schedule
heard by voice (hearing/answers.py, the first utterance cut), and every keyword and other sentence,
which must be neither. `--accept X` puts every keyword spotter's threshold (hearing/keywords.py ACCEPT)
under test.

Recordings are cached in /tmp (keyed by the conditions, the synthesiser's output and the source of
what renders and cuts them) so a second run decodes only. Not part of `python -m bench`: it measures
recognisers, not the system."""
from __future__ import annotations

import argparse
import base64
import dataclasses
import hashlib
import itertools
import math
import os
import pickle
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from .speech import DISTANCES, NOISE, ROBOT_AT, SPEEDS, TV_AT, VOCABULARY, VOICES

# sentences the owner may say that are no command, and "" (nobody speaks for 20 s: only the room's
# sound): never a RApp
OTHER = ("open the window please", "what time is it", "thank you very much", "turn on the radio",
         "where are my glasses", "hello there", "good morning robot", "")
CACHE = Path("/tmp/rapp-speech-offline")
VAD: dict[str, float] = {}  # VoiceActivity options under test (--vad pad=0.3)
ACOUSTICS: dict[str, float] = {}  # the house's reverberation under test (--rt60 0.5: rt60_s; --equal-tv: tv_db)
ARRAY: dict = {}  # the NAO's four microphones and a beamformer under test (--beam mvdr|das, --loading)
ACCEPT: dict[str, float] = {}  # the keyword threshold under test (--accept -0.02: accept)
PATHS = ("keyword", "platform", "supervision", "words", "confirm")
# the cognitive game's answers said alone (its word_spotting hears numbers 0-300 as words or digits)
ANSWERS = ("five", "six", "nine", "twelve", "twenty", "thirty five", "sixty", "one hundred", "pass")
# the owner's answers to the Core's question before it keeps a schedule heard by voice (hearing/answers.py)
CONFIRM = (("yes", "yes"), ("yeah", "yes"), ("yes please", "yes"), ("okay", "yes"), ("no", "no"), ("nope", "no"),
           ("no thanks", "no"), ("cancel", "no"))
MIC_Z = 0.50  # a NAO's microphones: its collision height + 0.05 (robots/microphones.py AudioInput)


def items(path: str) -> list[tuple[str, str | None]]:
    """(text, expected answer: a RApp, a supervision word's action, a number) of one path; the other
    sentences for every path, and for the supervision words every command too."""
    if path == "supervision":
        from agents.core_agent import SUPERVISION_WORDS
        commands = [(t, None) for ws, ps in VOCABULARY.values() for t in (*ws, *ps)]
        return sorted(SUPERVISION_WORDS.items()) + commands + [(t, None) for t in OTHER]
    if path == "confirm":  # every keyword too: a command said instead of an answer is none
        keywords = [(w, None) for ws, _ in VOCABULARY.values() for w in ws]
        return list(CONFIRM) + keywords + [(t, None) for t in OTHER]
    if path == "words":
        meaning = _answer_words()
        return [(a, meaning[a]) for a in ANSWERS] + [(t, None) for t in OTHER]
    said = [(w, rapp) for rapp, (ws, ps) in VOCABULARY.items() for w in (ws if path == "keyword" else ps)]
    return said + [(t, None) for t in OTHER]


def _answer_words() -> dict[str, str]:
    """What the cognitive game listens for -> the answer it means (its own table)."""
    from rapps.cognitive_game.cognitive_game.task import answer_words
    return answer_words([])


def conditions(path: str, quick: bool) -> list[tuple]:
    """(text, rapp, voice, speed, distance, noise): every sentence in every noise, voices, speeds and
    distances cycled so that each sentence meets several."""
    per = 2 if quick else 6
    out = []
    for k, ((text, rapp), noise) in enumerate(itertools.product(items(path), NOISE)):
        for i in range(per):
            j = k * per + i
            out.append((text, rapp, VOICES[j % len(VOICES)], SPEEDS[(j // 2) % len(SPEEDS)],
                        DISTANCES[(j * 3 + k) % len(DISTANCES)], noise))
    return out


def reverberant_gain_db(rt60_s: float) -> float:
    """How much louder the TV is at the robot's microphone with the living room's reverberation."""
    from robots.floorplan import load_plan
    from robots.reverb import critical_distance
    from robots.world import HOUSES

    plan = load_plan(HOUSES / "small.yaml", seed=5)
    r_c = critical_distance(plan.room_volume(plan.room_at(*ROBOT_AT)), rt60_s)
    return 10 * math.log10(1 + (math.dist(TV_AT, (*ROBOT_AT, MIC_Z)) / r_c) ** 2)


def heard_utterances(pcm: np.ndarray | None, distance: float, noise_db: float | None = None) -> list:
    """What the Core's voice activity detector cuts (HeardUtterance) from the owner saying `pcm` (None:
    nobody speaks for 20 s) `distance` m from the NAO in the small house, a TV at `noise_db` or off."""
    return [u for u, _, _ in timed_utterances(pcm, distance, noise_db)]


def _owner_in_the_house(pcm: np.ndarray | None, distance: float, noise_db: float | None):
    """(the house with the owner saying `pcm` from 4 s on, the TV at `noise_db` or off, the seconds to
    record, when the owner starts)."""
    from robots.floorplan import load_plan
    from robots.sound import HouseSound, NoiseSource, talker_at
    from robots.world import HOUSES

    room = {"acoustics": {"rt60_s": ACOUSTICS.get("rt60_s", 0.0)}}
    house = HouseSound(load_plan(HOUSES / "small.yaml", seed=5, overrides=room))
    if noise_db:
        house.add(NoiseSource("tv", TV_AT, kind="tv", level_db=noise_db + ACOUSTICS.get("tv_db", 0.0), seed=5,
                              start=0.0))
    at = 4.0  # the detector learns the room first, as the Core's does
    if pcm is None:
        pcm = np.zeros(20 * 16000, np.int16)
    else:
        house.play("owner", talker_at(ROBOT_AT, distance, MIC_Z), pcm, at=at, level_db=60)
    return house, at + len(pcm) / 16000 + 1.5, at


def recording(pcm: np.ndarray | None, distance: float, noise_db: float | None = None) -> np.ndarray:
    """The NAO's one microphone (as its word_spotting hears it) over the whole of heard_utterances' scene."""
    house, seconds, _ = _owner_in_the_house(pcm, distance, noise_db)
    return house.receive((*ROBOT_AT, MIC_Z), 0.0, seconds, mic="nao")


def timed_utterances(pcm: np.ndarray | None, distance: float, noise_db: float | None = None) -> list:
    """heard_utterances, each as (HeardUtterance, the detector's time it started, its time it was cut)."""
    from hearing.vad import VoiceActivity
    from robots.sound import talker_at

    house, seconds, at = _owner_in_the_house(pcm, distance, noise_db)
    if ARRAY.get("beam") == "located":
        return _located(house, seconds)
    if ARRAY:
        heard = _beamformed(house, talker_at(ROBOT_AT, distance, MIC_Z), seconds, quiet_until=at - 0.5)
    else:
        heard = house.receive((*ROBOT_AT, MIC_Z), 0.0, seconds, mic="nao")
    vad = VoiceActivity(max_seconds=5.0, **VAD)
    out = []
    for s in range(0, len(heard), 1600):
        out += [(u, vad.started_s, vad.cut_s) for u in vad.feed(heard[s:s + 1600])]
    return out


def _beamformed(house, owner, seconds: float, quiet_until: float) -> np.ndarray:
    """The NAO's four microphones (robots/mic_array.py), facing +x, steered to where the owner's mouth
    is (known here, as a sound localisation would estimate it), the noise estimated from the room
    before the owner speaks."""
    from hearing.steering import mvdr
    from robots.mic_array import NAO_MICS, arrival_delays, heads_mics

    mics = heads_mics(NAO_MICS, 0.0) + np.array([*ROBOT_AT, MIC_Z])[None]
    channels = house.receive_array(mics, 0.0, seconds, mic="nao").astype(np.float64)
    delays = arrival_delays(mics, owner)
    if ARRAY["beam"] == "das":
        out = mvdr(channels, np.zeros((len(mics), 16000)), delays, loading=1.0)  # white noise: delay and sum
    else:
        out = mvdr(channels, channels[:, :round(quiet_until * 16000)], delays, loading=ARRAY["loading"])
    return np.clip(np.round(out), -32768, 32767).astype(np.int16)


def _located(house, seconds: float) -> list:
    """timed_utterances as the Core hears them with four microphones (agents/core_behaviours.py
    MicrophoneStream): the detector on the first, the room's dominant sound taken out, cuts the
    utterance, which hearing/steering.py Steering hears again with all four, steered to where it came
    from."""
    from hearing.steering import Steering
    from hearing.vad import VoiceActivity
    from robots.mic_array import NAO_MICS, heads_mics

    channels = house.receive_array(heads_mics(NAO_MICS, 0.0) + np.array([*ROBOT_AT, MIC_Z])[None], 0.0, seconds,
                                   mic="nao")
    vad, steering = VoiceActivity(max_seconds=5.0, **VAD), Steering(NAO_MICS)
    out = []
    for s in range(0, channels.shape[1], 1600):
        for u, end in steering.listen(vad, channels[:, s:s + 1600]):
            got = None if u.too_long else steering.steered(len(u.pcm), end)
            out.append((u if got is None else dataclasses.replace(u, pcm=got[0], bearing=got[1]),
                        vad.started_s, vad.cut_s))
    return out


def _hearing_code() -> bytes:
    """The source of what renders and cuts a recording (the house's sound, the detector and the array's
    processing, this harness): a change to it makes new recordings (the options under test alone
    missed a change of code with the same options)."""
    import hearing.bands
    import hearing.steering
    import hearing.vad
    import robots.mic_array
    import robots.reverb
    import robots.sound
    files = [Path(m.__file__) for m in (hearing.bands, hearing.steering, hearing.vad, robots.mic_array, robots.reverb,
                                        robots.sound)]
    return hashlib.sha1(b"".join(f.read_bytes() for f in [*files, Path(__file__)])).digest()  # and this harness


_HEARING_CODE = _hearing_code()


def _record(cond: tuple, whole: bool = False):
    """heard_utterances of one condition, as (pcm, speech seconds, too long, started, cut, loud frames),
    or with `whole` its one microphone's whole recording; cached."""
    from hearing import tts

    text, _, voice, speed, dist, noise = cond
    pcm = tts.synthesize(text, voice, speed) if text else None
    # keyed by the speech too: a change to the synthesiser makes new recordings
    # (and by the detector's options and the room under test, if any)
    under_test = tuple(tuple(sorted(opts.items())) for opts in (VAD, ACOUSTICS, ARRAY) if opts)
    said = _HEARING_CODE + repr((cond[0],) + cond[2:] + under_test + (("whole",) if whole else ())).encode()
    key = hashlib.sha1(said + (b"" if pcm is None else pcm.tobytes())).hexdigest()[:16]
    f = CACHE / f"{key}.pkl"
    if f.exists():
        return pickle.loads(f.read_bytes())
    if whole:
        got = recording(pcm, dist, NOISE[noise])
    else:
        got = [(u.pcm, u.speech_seconds, u.too_long, t0, t1, u.loud)
               for u, t0, t1 in timed_utterances(pcm, dist, NOISE[noise])]
    CACHE.mkdir(exist_ok=True)
    f.write_bytes(pickle.dumps(got))
    return got


def _rapps():
    from ontology.services.interpretation import RAppDescription
    return [RAppDescription(name=n, keywords=ws, phrases=ps, robot_types=["nao"]) for n, (ws, ps) in VOCABULARY.items()]


def _vocabulary() -> dict[str, str]:
    return {w.lower(): n for n, (ws, _) in VOCABULARY.items() for w in ws}


_SPOTTER = None


def decide_keyword(utts: list) -> str | None:
    """s4a as the Core runs it, then s4b for an utterance not spotted: the first RApp decided."""
    global _SPOTTER
    from hearing.keywords import KeywordSpotter
    from hearing.vad import HeardUtterance
    vocab = _vocabulary()
    if _SPOTTER is None:
        _SPOTTER = KeywordSpotter(sorted(vocab), [p for _, ps in VOCABULARY.values() for p in ps], groups=vocab,
                                  **ACCEPT)
    for k, (pcm, speech, too_long, _, _, loud) in enumerate(utts):
        word = _SPOTTER.spot(HeardUtterance(pcm, speech, too_long, loud=loud))
        rapp = vocab.get(word.lower()) if word else _sentence(utts, k)
        if rapp:
            return rapp
    return None


def decide_supervision(utts: list) -> str | None:
    """The Core's supervision words during a task, spotted as agents/core_hearing.py
    CoreHearing.set_vocabulary builds its spotter (the Store's words compete; any share of the speech
    will do): the first word's action."""
    global _SUPERVISION
    from agents.core_agent import SUPERVISION_WORDS
    from hearing.keywords import KeywordSpotter
    from hearing.vad import HeardUtterance
    if _SUPERVISION is None:
        _SUPERVISION = KeywordSpotter(sorted(SUPERVISION_WORDS), sorted(_vocabulary()) + [
            p for _, ps in VOCABULARY.values() for p in ps], groups=SUPERVISION_WORDS, min_cover=0.0, **ACCEPT)
    for pcm, speech, too_long, _, _, loud in utts:
        word = _SUPERVISION.spot(HeardUtterance(pcm, speech, too_long, loud=loud))
        if word:
            return SUPERVISION_WORDS[word]
    return None


def decide_words(heard: np.ndarray) -> str | None:
    """The cognitive game's word_spotting on one microphone's recording, as robots/microphones.py
    spot_in_audio does it (the pieces speech_segments cuts, in order, each decoded with the game's
    words, longest first as the game asks, its last 8 s at most): the answer the first word found means."""
    global _WORDS
    from hearing.keywords import WordSpotter
    from hearing.vad import speech_segments
    meaning = _answer_words()
    if _WORDS is None:
        _WORDS = WordSpotter(sorted(meaning, key=lambda w: (-len(w), w)), **ACCEPT)
    for s, e in speech_segments(heard):
        word, _ = _WORDS.spot(heard[max(s, e - 8 * 16000):e])
        if word is not None:
            return meaning.get(word.lower())
    return None


_SUPERVISION = _WORDS = _ANSWERS = None


def decide_confirm(utts: list) -> str | None:
    """The Core's confirmation (agents/core_confirm.py): the first utterance cut after its question is
    the answer, "yes", "no" or none, heard as hearing/answers.py AnswerSpotter hears it (the Store's
    keywords and phrases competing, as the Core builds it)."""
    global _ANSWERS
    from hearing.answers import AnswerSpotter
    from hearing.vad import HeardUtterance
    if _ANSWERS is None:
        _ANSWERS = AnswerSpotter(sorted(_vocabulary()) + [p for _, ps in VOCABULARY.values() for p in ps], **ACCEPT)
    if not utts:
        return None
    pcm, speech, too_long, _, _, loud = utts[0]
    return _ANSWERS.spot(HeardUtterance(pcm, speech, too_long, loud=loud))


def decide_platform(utts: list) -> str | None:
    """s4b as the Core and Platform run it: each utterance in turn (the Core sends each), the first
    RApp interpreted."""
    for k in range(len(utts)):
        rapp = _sentence(utts, k)
        if rapp:
            return rapp
    return None


def _sentence(utts: list, k: int) -> str | None:
    """s4b on utterance k, joined with the next when the owner went on within the Core's pause
    (agents/core_hearing.py), the first part alone if the whole is not understood."""
    from agents.core_hearing import CONTINUE_WITHIN_S
    from hearing.vad import HeardUtterance

    pcm, speech, too_long, _, cut, loud = utts[k]
    heard = HeardUtterance(pcm, speech, too_long, loud=loud)
    if k + 1 < len(utts) and not utts[k + 1][2] and utts[k + 1][3] - cut < CONTINUE_WITHIN_S:
        more = utts[k + 1]
        rapp = _platform(heard.then(HeardUtterance(more[0], more[1], more[2], loud=more[5])))
        if rapp:
            return rapp
    return _platform(heard)


def _platform(heard) -> str | None:
    from agents.services import ServiceError, run_service
    from agents.services.context import ServiceContext, ServiceState
    from agents.services.interpretation import interpret
    from ontology.services.speech import SpeechRecognition
    from hearing.decoder import normalize
    from hearing.keywords import keyword_in_a_sentence
    from hearing.wav import encode_wav

    ctx = ServiceContext(user="bench", state=ServiceState(work_dir=Path("/tmp")))
    keywords = {normalize(k) for k in _vocabulary()}
    wav = base64.b64encode(encode_wav(heard.pcm)).decode()
    sentences = sorted({p for _, ps in VOCABULARY.values() for p in ps} | set(_vocabulary()))
    text = ""
    for allowed in (sentences, []):
        try:
            reply = run_service("speech_recognition", SpeechRecognition(audio_b64=wav, sentences=allowed), ctx)
        except ServiceError:
            return None
        # a keyword heard in a longer utterance: the general model hears it whole, as the Core has it
        text = "" if allowed and keyword_in_a_sentence(reply, keywords, heard) else reply.text
        if text.strip():
            break
    if not text.strip():
        return None
    try:
        return interpret(text, "nao", _rapps()).rapp
    except ServiceError:
        return None


def _one(args: tuple) -> dict:
    path, cond = args
    t0 = time.perf_counter()
    heard = _record(cond, whole=path == "words")
    t1 = time.perf_counter()
    got = {"keyword": decide_keyword, "platform": decide_platform, "supervision": decide_supervision,
           "words": decide_words, "confirm": decide_confirm}[path](heard)
    if path == "words":
        from hearing.vad import speech_segments
        heard = speech_segments(heard)
    return dict(path=path, text=cond[0], expected=cond[1], voice=cond[2], speed=cond[3], distance=cond[4],
                noise=cond[5], got=got, utterances=len(heard), decode_ms=(time.perf_counter() - t1) * 1e3,
                record_ms=(t1 - t0) * 1e3)


def report_confirm(mine: list[dict]) -> None:
    """The answers: yes and no said, heard right or as the other; anything else heard as yes or no."""
    print("confirm: yes said heard yes (as no), no said heard no (as yes), other speech heard as yes / as no")
    for noise in NOISE:
        at = [r for r in mine if r["noise"] == noise]
        yes, no, other = ([r for r in at if r["expected"] == e] for e in ("yes", "no", None))
        print(f"  {noise:6s} yes {sum(r['got'] == 'yes' for r in yes)}/{len(yes)} ({sum(r['got'] == 'no' for r in yes)})"
              f"   no {sum(r['got'] == 'no' for r in no)}/{len(no)} ({sum(r['got'] == 'yes' for r in no)})"
              f"   other {sum(r['got'] == 'yes' for r in other)} / {sum(r['got'] == 'no' for r in other)} of {len(other)}")
        print("         " + "  ".join(f"{v} {sum(r['got'] == r['expected'] for r in by)}/{len(by)}"
                                      for v in VOICES for by in [[r for r in yes + no if r["voice"] == v]]))


def report(rows: list[dict], show_wrong: bool) -> None:
    for path in PATHS:
        mine = [r for r in rows if r["path"] == path]
        if not mine:
            continue
        if path == "confirm":
            report_confirm(mine)
            if show_wrong:
                for r in mine:
                    if r["got"] != r["expected"]:
                        print(f"    {r['noise']:6s} {r['text']!r} {r['voice']} {r['speed']} {r['distance']} m"
                              f" -> {r['got']} ({r['utterances']} utterances)")
            continue
        print(f"{path}: right commands / commands (wrong RApps), other sentences taken as a command")
        for noise in NOISE:
            cmd = [r for r in mine if r["noise"] == noise and r["expected"]]
            other = [r for r in mine if r["noise"] == noise and not r["expected"]]
            right = sum(r["got"] == r["expected"] for r in cmd)
            wrong = sum(bool(r["got"]) and r["got"] != r["expected"] for r in cmd)
            print(f"  {noise:6s} {right:3d}/{len(cmd)} = {100 * right / max(len(cmd), 1):5.1f} % ({wrong} wrong)"
                  f"   other taken {sum(bool(r['got']) for r in other)}/{len(other)}")
            # by distance: the TV is 2.6 m from the robot, so the owner's distance sets the SNR
            print("         " + "  ".join(
                f"{d:g} m {sum(r['got'] == r['expected'] for r in at)}/{len(at)}"
                for d in DISTANCES for at in [[r for r in cmd if r["distance"] == d]]))
        ms = sorted(r["decode_ms"] for r in mine)
        print(f"  decode median {ms[len(ms) // 2]:.0f} ms, max {ms[-1]:.0f} ms")
        if show_wrong:
            for r in mine:
                if r["got"] != r["expected"]:
                    print(f"    {r['noise']:6s} {r['text']!r} {r['voice']} {r['speed']} {r['distance']} m"
                          f" -> {r['got']} ({r['utterances']} utterances)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.speech_offline", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 recordings per sentence and noise instead of 6")
    ap.add_argument("--only", choices=PATHS, help="one path (default: keyword and platform)")
    ap.add_argument("--show-wrong", action="store_true")
    ap.add_argument("--vad", action="append", default=[], metavar="NAME=VALUE",
                    help="a VoiceActivity option under test (recorded apart in the cache)")
    ap.add_argument("--rt60", type=float, default=0.0, metavar="S",
                    help="the living room's reverberation time (s); 0: anechoic, as the agent bench")
    ap.add_argument("--equal-tv", action="store_true",
                    help="with --rt60: the TV turned down so that it is as loud at the robot as in the anechoic room")
    ap.add_argument("--beam", choices=("mvdr", "das", "located"),
                    help="the NAO's four microphones, beamformed towards the owner's known place (delay and sum, or MVDR "
                         "on the room's noise), or as the Core hears them: the detector on the first with the room's dominant "
                         "sound taken out, each utterance located and beamformed (located)")
    ap.add_argument("--loading", type=float, default=1e-2, help="with --beam mvdr: its diagonal loading")
    ap.add_argument("--accept", type=float, metavar="X",
                    help="every keyword spotter's threshold (log-score per second against the phone loop) under test")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 2)
    a = ap.parse_args(argv)
    # the workers fork after this; counts (start_frames) stay whole numbers
    VAD.update((k, int(v) if v.lstrip("-").isdigit() else float(v)) for k, v in (o.split("=", 1) for o in a.vad))
    if a.rt60:
        ACOUSTICS["rt60_s"] = a.rt60
        if a.equal_tv:
            ACOUSTICS["tv_db"] = -reverberant_gain_db(a.rt60)
            print(f"the TV {-ACOUSTICS['tv_db']:.1f} dB down: as loud at the robot as without reverberation",
                  file=sys.stderr)
    if a.beam:
        ARRAY.update(beam=a.beam, **({"loading": a.loading} if a.beam == "mvdr" else {}))
    if a.accept is not None:
        ACCEPT["accept"] = a.accept
    paths = [a.only] if a.only else ["keyword", "platform"]
    jobs = [(p, c) for p in paths for c in conditions(p, a.quick)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as pool:
        rows = list(pool.map(_one, jobs, chunksize=4))
    report(rows, a.show_wrong)
    print(f"{len(rows)} recordings in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
