"""Cognitive game: choose a test, ask each question, listen for the answer, record the score.
Answers are heard as typed utterances or spoken in the room: numbers may be said as words
("fifty six", "two hundred twenty one")."""
from rapps.sdk import FSM, Step, Task

NUMBERS = range(0, 301)  # the answers the microphone listens for besides the question's own
ONES = ["zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten", "eleven", "twelve",
        "thirteen", "fourteen", "fifteen", "sixteen", "seventeen", "eighteen", "nineteen"]
TENS = ["", "", "twenty", "thirty", "forty", "fifty", "sixty", "seventy", "eighty", "ninety"]


def spoken(n: int) -> str:
    """A number as it is said: 56 -> "fifty six", 221 -> "two hundred twenty one"."""
    if n < 20:
        return ONES[n]
    if n < 100:
        return TENS[n // 10] + ("" if n % 10 == 0 else " " + ONES[n % 10])
    rest = n % 100
    return ONES[n // 100] + " hundred" + ("" if rest == 0 else " " + spoken(rest))


def answer_words(answers: list[str]) -> dict[str, str]:
    """What may be heard -> the answer it means (the canonical form: a number's digits)."""
    heard = {"pass": "pass"}
    for n in NUMBERS:
        heard[str(n)] = heard[spoken(n)] = str(n)
    for a in answers:
        key = a.lower()
        heard[key] = str(int(key)) if key.isdigit() else heard.get(key, key)
        if key.isdigit() and int(key) not in NUMBERS:
            heard[spoken(int(key))] = str(int(key))
    return heard


class QuizTask(Task):
    def build(self):
        fsm = FSM("quiz", initial="choose")
        fsm.add_state("choose", Step(self.choose))
        fsm.add_state("ask", Step(self.ask))
        fsm.add_state("score", Step(self.score), final=True)
        fsm.add_transition("choose", "ask")
        # ask again while questions remain (a condition over memory), then score
        fsm.add_transition("ask", "ask", when=lambda m, o: m["next"] < len(m["test"].questions))
        fsm.add_transition("ask", "score", when=lambda m, o: m["next"] >= len(m["test"].questions))
        return fsm

    async def choose(self, memory):
        memory["test"] = await self.platform.cognitive_test_chooser(
            test_type=str(self.params.get("test_type", "arithmetic")),
            difficulty=int(self.params.get("difficulty", 0)))
        memory["next"], memory["correct"] = 0, 0
        await self.tell(f"Let's play: {len(memory['test'].questions)} questions.")

    async def ask(self, memory):
        question = memory["test"].questions[memory["next"]]
        await self.tell(f"Question {memory['next'] + 1}: {question.q}")
        meaning = answer_words(question.answers)
        heard = await self.robot.word_spotting(words=sorted(meaning, key=lambda w: (-len(w), w)),  # longest first
                                               timeout=float(self.params.get("answer_timeout_s", 20)))
        said = meaning.get((heard.word or "").lower())
        right = said is not None and said in {meaning.get(a.lower()) for a in question.answers}
        memory["correct"] += int(right)
        memory["next"] += 1
        await self.tell("Correct!" if right else f"The answer was {question.answers[0]}.")

    async def score(self, memory):
        test = memory["test"]
        score = 100.0 * memory["correct"] / max(1, len(test.questions))
        await self.platform.cognitive_record_performance(test_id=test.test_id, score=score)
        await self.report(f"Quiz {test.test_id} finished: {memory['correct']} of {len(test.questions)} "
                          f"correct, score {score:.0f}.")

    async def tell(self, text: str) -> None:
        said = await self.say(text)  # False: no speech on this robot, the report carries it
        await self.report(text, said=said)  # chat; the Core does not say it again
