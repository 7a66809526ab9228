"""News explorer (paper 000 sec. 7, "news explorer via NAO"): the stories on a topic, or about the words
the owner said, from the Platform's news service; their titles and summaries are spoken and reported."""
from rapps.sdk import FSM, Step, Task

# words of a spoken subject that say nothing of it ("the news about the orchestra")
FILLERS = {"the", "a", "an", "of", "about", "on", "in", "some", "any", "today", "news"}


class NewsTask(Task):
    def build(self):
        fsm = FSM("news", initial="fetch")
        fsm.add_state("fetch", Step(self.fetch))
        fsm.add_state("tell", Step(self.tell), final=True)
        fsm.add_transition("fetch", "tell")
        return fsm

    async def fetch(self, memory):
        words = [w for w in str(self.params.get("topic") or "").lower().split() if w not in FILLERS]
        subject = " ".join(words)
        limit = int(self.params.get("max_stories", 3))
        reply = await self.platform.news_explore(topic=subject, max_stories=limit)
        if subject and not reply.stories:  # not one of the topics: the words of the subject, in any story
            reply = await self.platform.news_explore(keywords=words, max_stories=limit)
        memory["subject"], memory["stories"] = subject, reply.stories

    async def tell(self, memory):
        subject, stories = memory["subject"], memory["stories"]
        about = f" about {subject}" if subject else ""
        if not stories:
            lines = [f"I found no news{about}."]
        else:
            lines = [f"Here {'is one story' if len(stories) == 1 else f'are {len(stories)} stories'}{about}."]
            lines += [f"{i}. {s.title}. {s.summary}" for i, s in enumerate(stories, 1)]
        spoken = await self.say(*lines)
        await self.report(" ".join(lines) + ("" if spoken else " (I cannot speak, so I wrote it.)"),
                          stories=[s.title for s in stories])
