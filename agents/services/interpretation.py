"""Keyword / phrase / synonym matching of a spoken command against the RApps' manifests.

Score of a RApp = 3 per manifest phrase contained in the text + 1 per keyword whose concept (via the
synonym table) occurs in the text. The best-scoring RApp available for the robot type wins; ties and
zero scores are refused with a reason the Core can say to the user.

Parameters: a phrase may hold slots, `check the lamp in the {room}`; a command that fits the
phrase fills them (a slot takes one to three words). Besides, `city` (after "in" / "for", or a
known city name) for every RApp.

Schedules (paper 000 sec. 7, a task started "upon request from the user or executing a scheduled
task"): a command naming a time is a schedule's (`Interpretation.schedule`): "check the hazards
every day at 22:00", "... in ten minutes", "... tomorrow at 7 am", "cancel the evening check",
"what is scheduled?". The time is taken out before the RApp is matched; the robot's Core resolves
it against its own clock (agents/scheduler.py), which the Platform cannot know.
"""
from __future__ import annotations

import json
import re
from functools import lru_cache

from ontology.services.interpretation import (InterpretCommand, Interpretation, ScheduleAction, ScheduleRequest,
                                              When)
from ontology.errors import ErrorCode

from .context import DATA_DIR, ServiceContext
from .errors import ServiceError


@lru_cache(maxsize=1)
def synonyms() -> dict[str, str]:
    """word -> concept."""
    table = json.loads((DATA_DIR / "synonyms.json").read_text())
    return {w: concept for concept, words in table.items() for w in words + [concept]}


@lru_cache(maxsize=1)
def known_cities() -> dict[str, str]:
    data = json.loads((DATA_DIR / "weather.json").read_text())
    return {k: v["city"] for k, v in data.items()}


def normalize(text: str) -> str:
    t = text.lower().replace("e-mail", "email").replace("’", "'")
    return " ".join(re.findall(r"[a-z0-9']+", t))


def concepts(words: list[str]) -> set[str]:
    syn = synonyms()
    return {syn.get(w, w) for w in words} | set(words)


def extract_city(text: str) -> str | None:
    for k, city in known_cities().items():
        if re.search(rf"\b{k}\b", text.lower()):
            return city
    m = re.search(r"\b(?:in|for|at)\s+([A-Z][\w-]+(?:\s+[A-Z][\w-]+)?)", text)
    return m.group(1) if m else None


SLOT = re.compile(r"\{([a-z_][a-z0-9_]*)\}")
SLOT_VALUE = r"[a-z0-9']+(?: [a-z0-9']+){0,2}"


@lru_cache(maxsize=256)
def phrase_pattern(phrase: str) -> re.Pattern | None:
    """A phrase with {slots} as a regex over normalized text; None for a phrase without slots."""
    parts = SLOT.split(phrase.lower())
    if len(parts) == 1:
        return None
    tokens = [f"(?P<{part}>{SLOT_VALUE})" if i % 2 else re.escape(normalize(part))
              for i, part in enumerate(parts)]
    return re.compile(r"(?:^|(?<= ))" + " ".join(t for t in tokens if t) + "(?= |$)")


def match_phrase(phrase: str, norm: str) -> dict[str, str] | None:
    """The slot values when the normalized command contains the phrase, else None."""
    pattern = phrase_pattern(phrase)
    if pattern is None:
        p = normalize(phrase)
        return {} if p and f" {p} " in f" {norm} " else None
    m = pattern.search(norm)
    return None if m is None else {k: v for k, v in m.groupdict().items() if v}


def interpret(text: str, robot_type: str, rapps) -> Interpretation:
    norm = normalize(text)
    words = norm.split()
    have = concepts(words)
    scored = []
    for r in rapps:
        if r.robot_types and robot_type and robot_type not in r.robot_types:
            continue
        matched, score, slots = [], 0.0, {}
        for p in r.phrases:
            values = match_phrase(p, norm)
            if values is not None:
                matched.append(p)
                score += 3
                slots = {**values, **slots}  # the first phrase that fills a slot wins
        for k in r.keywords:
            kw = normalize(k)
            if kw and (kw in have or synonyms().get(kw, kw) in have):
                matched.append(k)
                score += 1
        scored.append((score, r.name, matched, slots))
    if not scored:
        raise ServiceError(f"no application is available for robot type {robot_type!r}", ErrorCode.NO_RAPP)
    scored.sort(key=lambda s: -s[0])
    best = scored[0]
    if best[0] == 0:
        raise ServiceError(f"I did not understand '{text}': it matches no application", ErrorCode.NOT_UNDERSTOOD)
    if len(scored) > 1 and scored[1][0] == best[0]:
        raise ServiceError(f"'{text}' could mean {best[1]} or {scored[1][1]}; please say it differently", ErrorCode.AMBIGUOUS)
    params = dict(best[3])
    city = extract_city(text)
    if city:
        params.setdefault("city", city)
    return Interpretation(rapp=best[1], parameters=params, score=best[0], matched=best[2])


def interpret_command(req: InterpretCommand, ctx: ServiceContext) -> Interpretation:
    schedule, rest = parse_schedule(req.text)
    if schedule is None:
        out = interpret(req.text, req.robot_type, req.rapps)
    elif schedule.action == ScheduleAction.ADD:  # what to start, without the time's words
        out = interpret(rest, req.robot_type, req.rapps).model_copy(update={"schedule": schedule})
    else:  # cancel or list: a RApp named narrows it, none is fine
        try:
            out = interpret(rest, req.robot_type, req.rapps) if rest.strip() else None
        except ServiceError:
            out = None
        out = (out or Interpretation(rapp="", score=0.0)).model_copy(update={"schedule": schedule})
    room = out.parameters.get("room")
    if room:  # as the caller's home names it: said "living room", it is the home's "living_room"
        from .home import homes
        named = room_named(room, homes(ctx.state).rooms(ctx.user))
        if named is not None:
            out = out.model_copy(update={"parameters": {**out.parameters, "room": named}})
    return out


def room_named(value: str, rooms: list[str]) -> str | None:
    """The room of `rooms` that is said (or typed) as `value`: names compare as words, so
    "Living Room", "living_room" and "living-room" are all said "living room"."""
    said = normalize(value)
    return next((r for r in rooms if normalize(r) == said), None)


# -- schedules: a time in the command ---------------------------------------------------------------
NUMBERS = {w: i for i, w in enumerate("zero one two three four five six seven eight nine ten eleven twelve thirteen "
                                      "fourteen fifteen sixteen seventeen eighteen nineteen twenty".split())}
NUMBERS.update({"thirty": 30, "forty": 40, "fifty": 50, "sixty": 60, "a": 1, "an": 1, "a couple of": 2})
_NUM = r"(?:\d+(?:\.\d+)?|(?:twenty|thirty|forty|fifty)(?:[ -](?:one|two|three|four|five|six|seven|eight|nine))?|" \
       r"a couple of|" + "|".join(sorted((w for w in NUMBERS if " " not in w), key=len, reverse=True)) + ")"
UNITS = {"second": 1, "sec": 1, "minute": 60, "min": 60, "hour": 3600, "hr": 3600}
PARTS = {"morning": "morning", "afternoon": "afternoon", "evening": "evening", "night": "night",
         "tonight": "evening"}
_IN = re.compile(rf"\b(?:in|within)\s+(?:(half an hour|a quarter of an hour|an hour and a half)|({_NUM})\s+"
                 rf"(seconds?|secs?|minutes?|mins?|hours?|hrs?))\b")
_AT = re.compile(rf"\bat\s+(?:(noon|midday|midnight)|(\d{{1,2}})(?::(\d{{2}}))?|({_NUM}))"
                 r"(?:\s*(a\.?\s?m\.?|p\.?\s?m\.?|o'?clock))?(?=\W|$)")  # "p m": as the recogniser spells pm
_DAILY = re.compile(r"\b(?:every\s*day|each day|daily|every (morning|afternoon|evening|night))\b")
_DAY = re.compile(r"\b(today|tonight|tomorrow)\b")
_DATE = re.compile(r"\bon\s+(\d{4}-\d{2}-\d{2})\b")
_PART = re.compile(r"\b(?:in the |this )?(morning|afternoon|evening|night|tonight)\b")
_CANCEL = re.compile(r"^\W*(?:please\s+)?(?:cancel|remove|delete|forget|unschedule|call off|drop)\b")
_EVERY = re.compile(r"\b(?:all|every|each)\b(?!\s*day)")
_LIST = re.compile(r"\b(?:what(?:'s| is| are)|which|list|show|tell me)\b.*\b(?:schedul\w*|planned)\b")


def number(word: str) -> float:
    word = word.strip()
    if word in NUMBERS:
        return NUMBERS[word]
    if re.fullmatch(r"\d+(?:\.\d+)?", word):
        return float(word)
    tens, _, unit = word.replace("-", " ").partition(" ")
    return NUMBERS[tens] + NUMBERS.get(unit, 0)


def parse_schedule(text: str) -> tuple[ScheduleRequest | None, str]:
    """The schedule a command asks for, and the command without its time words; (None, text) when
    it names no time. ServiceError for a time said wrong (25:00, "every day" with no time)."""
    said = " ".join(text.replace("’", "'").split())
    low = said.lower()
    if len(low) != len(said):  # a character whose lower case is longer: the spans index the lower text
        said = low
    if _LIST.search(low):
        return ScheduleRequest(action=ScheduleAction.LIST), ""
    cancel = _CANCEL.search(low)
    spans: list[tuple[int, int]] = [cancel.span()] if cancel else []
    when, daily, part = None, _DAILY.search(low), None
    m_in, m_at = _IN.search(low), _AT.search(low)
    day, date = _DAY.search(low), _DATE.search(low)
    for m in (daily, day, date):
        if m:
            spans.append(m.span())
    evening = bool(day and day.group(1) == "tonight") or bool(daily and daily.group(1) in ("evening", "night"))
    m_part = _PART.search(low)
    if m_part and not (daily and m_part.start() >= daily.start()):
        part = PARTS[m_part.group(1)]
        evening = evening or part in ("evening", "night", "afternoon")
        spans.append(m_part.span())
    if m_in:
        spans.append(m_in.span())
        phrase, count, unit = m_in.groups()
        seconds = {"half an hour": 1800, "a quarter of an hour": 900, "an hour and a half": 5400}.get(phrase) \
            if phrase else number(count) * UNITS[unit.rstrip("s")]
        when = When(kind="in", seconds=seconds)
    elif m_at:
        spans.append(m_at.span())
        hour, minute = _clock_time(m_at, evening)
        if daily:
            when = When(kind="daily", hour=hour, minute=minute)
        else:
            when = When(kind="at", hour=hour, minute=minute, date=date.group(1) if date else None,
                        day=None if date or not day else "tomorrow" if day.group(1) == "tomorrow" else "today")
    elif daily and not cancel:
        raise ServiceError(f"at what time? Say it with one, as in \"{text.strip()} at 22:00\"", ErrorCode.INVALID)
    if cancel:
        if _EVERY.search(low):
            spans.append(_EVERY.search(low).span())
        time_of_day = when if when is not None and when.kind != "in" else None
        part = part or (daily.group(1) if daily and daily.group(1) else None)
        return ScheduleRequest(action=ScheduleAction.CANCEL, when=time_of_day, part_of_day=part,
                               every=bool(_EVERY.search(low))), _without(said, spans)
    if when is None:
        return None, text
    return ScheduleRequest(action=ScheduleAction.ADD, when=when), _without(said, spans)


def _clock_time(m: re.Match, evening: bool) -> tuple[int, int]:
    named, digits, minutes, words, suffix = m.groups()
    if named:
        return (0 if named == "midnight" else 12), 0
    hour, minute = (int(digits), int(minutes or 0)) if digits else (int(number(words)), 0)
    suffix = (suffix or "").replace(".", "").replace(" ", "")
    if hour > 23 or minute > 59 or (suffix in ("am", "pm") and not 1 <= hour <= 12):
        raise ServiceError(f"{m.group(0)[3:].strip()} is not a time of day", ErrorCode.INVALID)
    if suffix == "pm" and hour < 12:
        hour += 12
    elif suffix == "am" and hour == 12:
        hour = 0
    elif not suffix.endswith("m") and evening and hour < 12 and minutes is None:
        hour += 12  # "tonight at ten", "every evening at 9"
    return hour, minute


def _without(text: str, spans: list[tuple[int, int]]) -> str:
    keep = [ch if not any(a <= i < b for a, b in spans) else " " for i, ch in enumerate(text)]
    return " ".join("".join(keep).split())


# -- schedules as they are said: what the speech recogniser listens for after a command ---------------
# (the Core asks speech_recognition with `times`: each Store sentence may end with one of these, and
# the schedules' own sentences are heard; parse_schedule above reads every one of them)
_HOURS = "one two three four five six seven eight nine ten eleven twelve".split()
_COUNTS = _HOURS[1:] + ["fifteen", "twenty", "twenty five", "thirty", "forty", "forty five", "fifty"]
_DAYS = ["every day", "each day", "every morning", "every afternoon", "every evening", "every night",
         "tomorrow", "tonight", "today"]
_DELAYS = ["a minute", "one minute", "an hour", "one hour", "half an hour", "a quarter of an hour",
           "an hour and a half"]
SAID_TIMES_JSGF = f"""
<suffix> = [{' | '.join(_DAYS)}] at <clock> | in <delay>;
<clock> = ({' | '.join(_HOURS)}) [o'clock | a m | p m] | noon | midnight;
<delay> = ({' | '.join(_COUNTS)}) (minutes | hours) | {' | '.join(_DELAYS)};
"""
_SAID_CLOCK = rf"(?:(?:{'|'.join(_HOURS)})(?: o'clock| a m| p m)?|noon|midnight)"
_SAID_TIME = re.compile(rf"(?:(?:{'|'.join(_DAYS)}) )?at {_SAID_CLOCK}|in (?:(?:{'|'.join(_COUNTS)}) (?:minutes|hours)|"
                        rf"{'|'.join(_DELAYS)})")
SCHEDULE_SENTENCES = ["what is scheduled", "what's scheduled", "cancel the check", "cancel all the checks",
                      "cancel the morning check", "cancel the afternoon check", "cancel the evening check",
                      "cancel the night check"]


def said_time(words: str) -> bool:
    """Whether `words` are a whole time as SAID_TIMES_JSGF lets it be said ("every day at ten p m")."""
    return _SAID_TIME.fullmatch(words) is not None
