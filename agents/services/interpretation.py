"""Keyword / phrase / synonym matching of a spoken command against the RApps' manifests.

Score of a RApp = 3 per manifest phrase contained in the text + 1 per keyword whose concept (via the
synonym table) occurs in the text. The best-scoring RApp available for the robot type wins; ties and
zero scores are refused with a reason the Core can say to the user.

Parameters: a phrase may hold slots, `check the lamp in the {room}`; a command that fits the
phrase fills them (a slot takes one to three words). Besides, `city` (after "in" / "for", or a
known city name) for every RApp.
"""
from __future__ import annotations

import json
import re
from functools import lru_cache

from ontology.services.interpretation import InterpretCommand, Interpretation
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
    out = interpret(req.text, req.robot_type, req.rapps)
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
