"""The Core's keyword spotter on the owner's synthesised speech, cut by its voice activity detector:
a keyword scoring a little below the free phone loop is still the keyword (hearing/keywords.py
ACCEPT), where a bound of 0 refuses it; a sentence is none."""
import pytest

from bench.speech_offline import heard_utterances
from hearing import tts
from hearing.keywords import ACCEPT, KeywordSpotter

KEYWORDS = {"hazards": "hazard_detection", "hazard": "hazard_detection", "weather": "weather_reporter",
            "forecast": "weather_reporter", "email": "email_reader", "mail": "email_reader",
            "inbox": "email_reader", "game": "cognitive_game", "quiz": "cognitive_game"}
PHRASES = ["check the hazards", "are the doors closed", "what's the weather like", "tell me the forecast",
           "read my e-mail", "check my inbox", "let's play a game", "give me a quiz"]


def _utterances(text: str, voice: str, speed: int, distance: float):
    return heard_utterances(tts.synthesize(text, voice, speed), distance)  # the speech harness's recording


def _spotter(accept=ACCEPT):
    return KeywordSpotter(sorted(KEYWORDS), PHRASES, groups=KEYWORDS, accept=accept)


# keywords said in a quiet room whose paths scored a little below the phone loop's (within 0.04 per
# second) on bench/speech_offline.py's recordings: refused at the old bound of 0
CLOSE_CALLS = [("hazards", "en", 160, 1.0), ("hazard", "en", 130, 1.0), ("weather", "en-us+f3", 190, 1.0),
               ("email", "en-us+m3", 130, 0.5), ("email", "en-us", 160, 1.0), ("email", "en-us+f3", 190, 0.5),
               ("inbox", "en-us+f3", 160, 3.0)]


def test_keywords_a_little_below_the_phone_loop_are_the_keywords():
    # counted over several, not judged one by one: the margins are within 0.04 of the bound, and a
    # small change to the synthesiser or the house moves them (eSpeak NG's output moved with what a
    # process had synthesised before, until hearing/tts.py loaded it afresh per call). One spotter of
    # each bound decides them all, as the Core's does: a decision depends on its own audio only.
    at_accept, at_zero = [], []
    loose, strict = _spotter(), _spotter(0.0)
    for said, voice, speed, distance in CLOSE_CALLS:
        utts = _utterances(said, voice, speed, distance)
        at_accept.append(next((w for u in utts if (w := loose.spot(u))), None))
        at_zero.append(next((w for u in utts if (w := strict.spot(u))), None))
    rapps = [KEYWORDS[c[0]] for c in CLOSE_CALLS]  # "inbox" heard as "email" starts the same RApp
    assert all(w is None or KEYWORDS[w] == r for w, r in zip(at_accept + at_zero, rapps + rapps)), (at_accept, at_zero)
    assert sum(map(bool, at_accept)) >= sum(map(bool, at_zero)) + 2, (at_accept, at_zero)


# the middle three were each taken for a keyword (email, hazards, email) that covered 0.4-0.7 of the
# speech heard, before the spotter asked a keyword alone to cover most of it (KeywordSpotter.MIN_COVER);
# the last one for "weather", covering 0.79 of it with 0.13 s of speech before it, until a keyword alone
# had to leave no more than MAX_OTHER_SPEECH_S outside (hearing/keywords.py said_alone). The third
# needs that rule too since the detector no longer holds an utterance open for one loud frame
@pytest.mark.parametrize("said,voice,speed,distance", [
    ("thank you very much", "en-us", 160, 1.0), ("hello there", "en+f2", 160, 1.0),
    ("thank you very much", "en-us+f3", 160, 0.5), ("where are my glasses", "en", 190, 1.0),
    ("turn on the radio", "en-us", 190, 0.5), ("hello there", "en-us+m3", 190, 1.0)])
def test_a_sentence_is_no_keyword(said, voice, speed, distance):
    utts = _utterances(said, voice, speed, distance)
    assert utts and all(_spotter().spot(u) is None for u in utts)


# in a furnished room (reverberation time 0.6 s) the detector hears a word's echo as speech for a few
# hundred ms after it: these keywords, said alone, covered 0.40-0.72 of the speech heard and were
# refused until the echo (ECHO_DB below the words) was left out (hearing/keywords.py said_alone)
ALONE_IN_A_ROOM = [("email", "en-us", 160, 1.0), ("forecast", "en-us", 130, 2.0), ("hazards", "en-us", 130, 0.5),
                   ("quiz", "en", 190, 0.5), ("weather", "en-us+f3", 190, 1.0)]
# and these sentences, taken for a keyword there, stay refused: their other words are as loud as it
SENTENCES_IN_A_ROOM = [("thank you very much", "en-us+f3", 160, 0.5), ("where are my glasses", "en", 190, 1.0),
                       ("what time is it", "en-us", 190, 1.0)]


def test_a_keyword_said_alone_in_a_furnished_room_is_its_echo_and_no_more(monkeypatch):
    import bench.speech_offline as harness
    monkeypatch.setitem(harness.ACOUSTICS, "rt60_s", 0.6)
    spotter = _spotter()
    alone = [next((w for u in _utterances(*said) if (w := spotter.spot(u))), None) for said in ALONE_IN_A_ROOM]
    assert [KEYWORDS.get(w) for w in alone] == [KEYWORDS[s[0]] for s in ALONE_IN_A_ROOM], alone
    sentences = [w for said in SENTENCES_IN_A_ROOM for u in _utterances(*said) if (w := spotter.spot(u))]
    assert sentences == []
