"""Task of the ``hello`` example RApp: the smallest complete task built on the SDK."""
from rapps.sdk import FSM, Step, Task


class HelloTask(Task):
    """Says the configured greeting (or writes it when the robot cannot speak), then finishes."""

    def build(self):
        fsm = FSM("hello", initial="greet")
        fsm.add_state("greet", Step(self.greet), final=True)
        return fsm

    async def greet(self, memory):
        text = str(self.params.get("greeting", "Hello"))
        await self.say(text)  # an Elektron cannot speak: the report carries the greeting
        await self.report(text)
