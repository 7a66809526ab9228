"""Cognitive exercises: choose a test by type and difficulty, record scores, per-user history."""
from __future__ import annotations

import json
import random
import secrets
import threading
import time

from ontology.services.knowledge import (
    ChooseCognitiveTest, CognitiveHistory, CognitiveTest, GetHistory, RecordPerformance, ScoreRecord,
)
from ontology.errors import ErrorCode

from .context import ServiceContext
from .errors import ServiceError


class ExerciseStore:
    """Tests loaded from data/cognitive_tests.json and each user's score history (kept in `saved`,
    agents/services/saved.py, if given)."""

    KIND = "cognitive"

    def __init__(self, tests: list[dict], saved=None) -> None:
        self.tests = {t["id"]: t for t in tests}
        self.history: dict[str, list[ScoreRecord]] = {}
        self.lock = threading.Lock()
        self._saved = saved
        for rec in saved.records(self.KIND) if saved is not None else ():
            self.history.setdefault(rec.user, []).append(ScoreRecord.model_validate(rec.meta))
        for records in self.history.values():
            records.sort(key=lambda r: r.time)

    def records(self, user: str, test_type: str = "") -> list[ScoreRecord]:
        with self.lock:
            return [r for r in self.history.get(user, []) if not test_type or r.type == test_type]

    def add(self, user: str, rec: ScoreRecord) -> None:
        if self._saved is not None:
            self._saved.put(self.KIND, user, f"{rec.time:.6f}-{secrets.token_hex(4)}", rec.model_dump(mode="json"))
        with self.lock:
            self.history.setdefault(user, []).append(rec)


def store(ctx: ServiceContext) -> ExerciseStore:
    return ctx.state.store("cognitive", lambda: ExerciseStore(
        json.loads((ctx.state.data_dir / "cognitive_tests.json").read_text()), ctx.state.saved))


def adaptive_difficulty(records: list[ScoreRecord]) -> int:
    """Start at 1; go up after a score >= 75, down after one < 40."""
    if not records:
        return 1
    last = records[-1]
    step = 1 if last.score >= 75 else -1 if last.score < 40 else 0
    return min(3, max(1, last.difficulty + step))


def choose_test(req: ChooseCognitiveTest, ctx: ServiceContext) -> CognitiveTest:
    s = store(ctx)
    of_type = [t for t in s.tests.values() if t["type"] == req.test_type]
    if not of_type:
        types = sorted({t["type"] for t in s.tests.values()})
        raise ServiceError(f"unknown test type {req.test_type!r} (known: {', '.join(types)})", ErrorCode.UNKNOWN_TEST_TYPE)
    level = req.difficulty or adaptive_difficulty(s.records(ctx.user, req.test_type))
    pool = [t for t in of_type if t["difficulty"] == level] or \
        sorted(of_type, key=lambda t: abs(t["difficulty"] - level))[:1]
    done = {r.test_id for r in s.records(ctx.user)}
    t = random.choice([t for t in pool if t["id"] not in done] or pool)
    return CognitiveTest(test_id=t["id"], type=t["type"], difficulty=t["difficulty"], questions=t["questions"])


def record_performance(req: RecordPerformance, ctx: ServiceContext) -> ScoreRecord:
    s = store(ctx)
    t = s.tests.get(req.test_id)
    if t is None:
        raise ServiceError(f"unknown test {req.test_id!r}", ErrorCode.UNKNOWN_TEST)
    rec = ScoreRecord(test_id=t["id"], type=t["type"], difficulty=t["difficulty"], score=req.score, time=time.time())
    s.add(ctx.user, rec)
    return rec


def get_history(req: GetHistory, ctx: ServiceContext) -> CognitiveHistory:
    return CognitiveHistory(records=store(ctx).records(ctx.user, req.test_type))
