"""E-mail reader: fetch the user's unread mail and read it out."""
from rapps.sdk import FSM, Step, Task

MAX_BODY = 300  # characters read aloud per message


class EmailTask(Task):
    def build(self):
        fsm = FSM("email", initial="fetch")
        fsm.add_state("fetch", Step(self.fetch))
        fsm.add_state("read", Step(self.read), final=True)
        fsm.add_transition("fetch", "read")
        return fsm

    async def fetch(self, memory):
        reply = await self.platform.email_fetch(unread_only=True, mark_read=True,
                                                max_messages=int(self.params.get("max_messages", 5)))
        memory["messages"] = reply.messages

    async def read(self, memory):
        messages = memory["messages"]
        if not messages:
            lines = ["You have no new e-mail."]
        else:
            lines = [f"You have {len(messages)} new e-mail{'s' if len(messages) > 1 else ''}."]
            for m in messages:
                body = m.body.strip().replace("\n", " ")
                body = body[:MAX_BODY] + ("..." if len(body) > MAX_BODY else "")
                lines.append(f"From {m.sender}, subject {m.subject or '(none)'}: {body}")
        await self.say(*lines)  # no speech on this robot: the report below carries the text
        await self.report(" ".join(lines))
