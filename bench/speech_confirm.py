"""Schedules said aloud, and the Core's confirmation of them (agents/core_confirm.py), without agents.

The Platform's search of the Store's sentences with times (agents/services/speech.py, `times`) on the
recordings docs/sound.md's table "Schedules said aloud" was measured on: six schedules and five
sentences that are none, eSpeak NG's en-us, en-us+f3 and en-us+m3 at 0.5 and 1 m in the small house,
quiet, with the Store's sentences of tests/services/test_speech.py. Each recording heard as a new
schedule is then asked about, and the owner answers in the same voice at the same distance, as the
Core hears it (the answer cut by its voice activity detector, hearing/answers.py AnswerSpotter with the
Store's sentences competing): "yes" when the schedule heard is the one said, "no" when it is not (a
wrong hour, or no schedule said at all), and "yes" to a sentence misheard as a schedule too, the
owner not listening (the worst case). A schedule is kept when the answer is heard as "yes".

    python -m bench.speech_confirm [--workers N]

The yes / no recogniser alone, across the speech bench's voices, speeds, distances and TV:
`python -m bench.speech_offline --only confirm [--beam located]`."""
from __future__ import annotations

import argparse
import itertools
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

SCHEDULES = ("check the hazards every day at ten p m", "read my email in ten minutes",
             "tell me the news tonight at eleven", "check the hazards tomorrow at seven a m",
             "play a game every evening at nine", "tell me the news in twenty minutes")
NOT_SCHEDULES = ("do i have new mail from my son", "tell me the news about the weather", "play a game with me now",
                 "thank you very much", "check the hazards and then go to sleep")
PHRASES = ["check the hazards", "what is the weather", "read my email", "play a game", "tell me the news",
           "hello robot", "stop"]  # the Store's sentences of tests/services/test_speech.py
VOICES = ("en-us", "en-us+f3", "en-us+m3")
DISTANCES = (0.5, 1.0)
MIC = (1.0, 2.4, 0.5)


def _heard(text: str, distance: float, voice: str):
    """tests/services/test_speech.py's recording: the owner `distance` m from the NAO's microphone in
    the small house, the door d1 closed, quiet."""
    from hearing import tts
    from robots.floorplan import load_plan
    from robots.sound import HouseSound
    from robots.world import HOUSES

    house = HouseSound(load_plan(HOUSES / "small.yaml", seed=1, overrides={"doors": {"d1": 0}}))
    speech = tts.synthesize(text, voice)
    house.play("owner", (MIC[0] + distance, MIC[1], 1.6), speech, at=0.5, level_db=60)
    return house.receive(MIC, 0.0, len(speech) / 16000 + 1.0, mic="nao")


def _schedule(text: str) -> tuple | None:
    """What a text means as a new schedule: (rapp's sentence, kind, hour, minute, seconds), or None."""
    from agents.services.interpretation import parse_schedule
    from ontology.services.interpretation import ScheduleAction

    asked, rest = parse_schedule(text)
    if asked is None or asked.action != ScheduleAction.ADD or asked.when is None:
        return None
    w = asked.when
    return rest.strip(), w.kind, w.hour, w.minute, w.seconds, w.day


_ANSWERS = None


def _answer(said: str, voice: str, distance: float) -> str | None:
    """The Core's hearing of the owner's answer: the first utterance its detector cuts, yes / no / None."""
    global _ANSWERS
    from hearing import tts
    from hearing.answers import AnswerSpotter

    from .speech_offline import heard_utterances
    if _ANSWERS is None:
        _ANSWERS = AnswerSpotter(PHRASES)
    utts = heard_utterances(tts.synthesize(said, voice), distance)
    return _ANSWERS.spot(utts[0]) if utts else None


def _one(cond: tuple) -> dict:
    import base64

    from agents.services import run_service
    from agents.services.context import ServiceContext
    from hearing.wav import encode_wav
    from ontology.services.speech import SpeechRecognition

    text, voice, distance = cond
    ctx = ServiceContext(user="bench", state=None)
    wav = base64.b64encode(encode_wav(_heard(text, distance, voice))).decode()
    heard = run_service("speech_recognition", SpeechRecognition(audio_b64=wav, sentences=PHRASES, times=True), ctx).text
    meant, got = _schedule(text), _schedule(heard) if heard else None
    row = dict(text=text, voice=voice, distance=distance, heard=heard, schedule=meant is not None,
               asked=got is not None, right=got is not None and got == meant)
    if got is not None:  # the Core asks; the owner says yes to the schedule said, no to anything else
        row["answer_said"] = "yes" if row["right"] else "no"
        row["answer_heard"] = _answer(row["answer_said"], voice, distance)
        row["careless_heard"] = _answer("yes", voice, distance)  # an owner who says yes to anything
        row["kept"] = row["answer_heard"] == "yes"
    return row


def report(rows: list[dict]) -> None:
    said = [r for r in rows if r["schedule"]]
    other = [r for r in rows if not r["schedule"]]
    wrong = [r for r in said if r["asked"] and not r["right"]]
    print(f"schedules said: {len(said)}; heard as a schedule {sum(r['asked'] for r in said)}, the one said "
          f"{sum(r['right'] for r in said)}, another ({len(wrong)}): " + "; ".join(f"{r['text']!r} as {r['heard']!r} "
                                                                                 f"({r['voice']}, {r['distance']} m)"
                                                                                 for r in wrong))
    print(f"  the owner says yes to the right ones: kept {sum(r['kept'] for r in said if r['right'])}; "
          f"no to the others: kept {sum(r['kept'] for r in wrong)}")
    misheard = [r for r in other if r["asked"]]
    print(f"sentences that are no schedule: {len(other)}; heard as one {len(misheard)}")
    for r in misheard:
        print(f"  {r['text']!r} ({r['voice']}, {r['distance']} m) as {r['heard']!r}: the owner says no, heard "
              f"{r['answer_heard']}; said yes, heard {r['careless_heard']}")
    print(f"  kept now (the owner says no): {sum(r['kept'] for r in misheard)} of {len(misheard)}; before the "
          f"confirmation: {len(misheard)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.speech_confirm", description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 2)
    a = ap.parse_args(argv)
    conds = list(itertools.product(SCHEDULES + NOT_SCHEDULES, VOICES, DISTANCES))
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as pool:
        rows = list(pool.map(_one, conds, chunksize=2))
    report(rows)
    print(f"{len(rows)} recordings in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
