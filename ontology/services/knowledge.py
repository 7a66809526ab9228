"""Knowledge services: ontology queries over household objects and cognitive exercises."""
from __future__ import annotations

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, action


class ClassList(Content):
    classes: list[str]


@action("ontology_subclasses_of", ontology="platform", reply=ClassList, group="knowledge", idempotent=True)
class SubclassesOf(ServiceRequest):
    """The subclasses of `cls` in the household ontology (direct ones, or all with `recursive`)."""

    cls: str
    recursive: bool = True


@action("ontology_superclasses_of", ontology="platform", reply=ClassList, group="knowledge", idempotent=True)
class SuperclassesOf(ServiceRequest):
    """The superclasses of `cls` in the household ontology (direct ones, or all with `recursive`)."""

    cls: str
    recursive: bool = True


class IsSubclass(Content):
    result: bool


@action("ontology_is_subclass_of", ontology="platform", reply=IsSubclass, group="knowledge", idempotent=True)
class IsSubclassOf(ServiceRequest):
    """Whether `child` is a subclass of `parent` in the household ontology."""

    child: str
    parent: str


class Question(Content):
    q: str
    answers: list[str]


class CognitiveTest(Content):
    test_id: str
    type: str
    difficulty: int
    questions: list[Question]


@action("cognitive_test_chooser", ontology="platform", reply=CognitiveTest, group="cognitive")
class ChooseCognitiveTest(ServiceRequest):
    """Picks a test of the type; difficulty 0 = adapt to the user's last scores of that type."""

    test_type: str
    difficulty: int = Field(default=0, ge=0, le=3)


class ScoreRecord(Content):
    test_id: str
    type: str
    difficulty: int
    score: float  # 0..100
    time: float


@action("cognitive_record_performance", ontology="platform", reply=ScoreRecord, group="cognitive")
class RecordPerformance(ServiceRequest):
    """Record the user's score in a test (cognitive_test_chooser's `test_id`)."""

    test_id: str
    score: float = Field(ge=0, le=100)


class CognitiveHistory(Content):
    records: list[ScoreRecord]


@action("cognitive_get_history", ontology="platform", reply=CognitiveHistory, group="cognitive",
        idempotent=True)
class GetHistory(ServiceRequest):
    """The user's recorded cognitive test scores (of one test type, or all)."""

    test_type: str = ""
