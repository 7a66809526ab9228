"""Cognitive game: choose a test, ask each question, listen for the answer, record the score."""
from rapps.sdk import FSM, Step, Task

NUMBERS = [str(n) for n in range(0, 301)]  # spoken numbers the microphone listens for


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
        words = sorted(set(question.answers) | set(NUMBERS) | {"pass"})
        heard = await self.robot.word_spotting(words=words, timeout=float(self.params.get("answer_timeout_s", 20)))
        right = heard.word is not None and heard.word.lower() in {a.lower() for a in question.answers}
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
        await self.say(text)  # no speech on this robot: the chat report below carries it
        await self.report(text)
