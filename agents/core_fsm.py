"""The Core Agent's FSM, state by state as in fig. 5 of paper 000.

    s0 init -> s1 register -> s2 vocabulary -> s3 listen -> s4a keyword -> s5 download
                                                   (not a keyword alone) -> s4b platform -> s5
                                                   (a time named) -> s4b -> s4c schedule -> s3
      -> s6 activate (spawn a_dyn, hand supervision over) -> s8 serve -> s10 destroy (reap a_dyn,
      resume supervision) -> s3

    s9 (the double circle: one robot-API request of a_dyn, served while the FSM waits in s8):
        lock (the device's) -> act <-> held (the emergency stop latched) ; act -> release
        resources (a_dyn's own lock / free of a resource, paper 003)

s9's requests come concurrently (a motion with feedback while the pose is read): each is one pass
of its own instance of `build_command_fsm`, run by the command server as the request comes, while
the Core's FSM stays in s8; every state entered is a trace record (`fsm` "core.s9", with the
request's `conversation_id`).

s3 takes a command as text (chat, typed microphone utterances) or as speech (the microphone's sound,
cut into utterances by voice activity detection). s4's two branches are the figure's: an isolated
keyword is mapped to its RApp on the robot (s4a: pocketsphinx with the vocabulary of s2); anything
else goes to the Platform (s4b: speech_recognition for speech, then interpret_command).
A schedule come due (agents/scheduler.py) enters s3 as a command the Core knows and takes s4a,
as an isolated keyword does; s4c (not in the figure: the paper's sec. 7 trigger) keeps, cancels or
lists schedules when the Platform's interpretation names a time, and tells the owner; a new schedule
heard by voice is kept only when the owner says yes to it (agents/core_confirm.py).
A failed recognition or interpretation tells the user why (spoken: "Sorry, I did not understand")
and returns to s3; so does a failed download; a failed activation goes through s10 so nothing is
left running.
"""
from __future__ import annotations

import asyncio
import logging

from behaviours import FSM, Behaviour, OneShot
from hearing.vad import HeardUtterance

from .errors import RequestError
from .scheduler import ScheduledStart

log = logging.getLogger("rapp.core")
LISTEN = "s3_listen"  # the state the Core waits for a command in (CoreAgent.listening)


class CoreState(OneShot):
    """A state of the Core's FSM: one step of work on `self.core` (the CoreAgent)."""

    @property
    def core(self):
        return self.agent


class Init(CoreState):  # s0
    async def action(self):
        self.core.record_structure("init", robot=self.core.robot_id, robot_type=self.core.robot_type)


class Register(CoreState):  # s1: Platform and Store, retried with back-off until both answer
    async def action(self):
        delay = 0.2
        while True:
            try:
                await self.core.register_everywhere()
                return
            except RequestError as e:
                log.warning("%s: registration failed (%s); retry in %.1fs", self.core.address, e, delay)
                await asyncio.sleep(delay)
                delay = min(delay * 2, 5.0)


class Vocabulary(CoreState):  # s2: the Store's RApps for this robot type; keywords -> RApp
    async def action(self):
        await self.core.refresh_catalogue()  # again in s4 when a command names no known RApp
        await self.core.subscribe_catalogue()  # and whenever the Store says it changed


class Listen(Behaviour):  # s3: wait for the user's next command (chat or microphone)
    period = 0.0

    async def transition(self):
        self.memory["command"] = await self.agent.next_command()

    def terminal(self):
        return self.iterations >= 1


class Keyword(CoreState):  # s4a: an isolated keyword -> its RApp, here on the robot (or a schedule come due)
    async def action(self):
        command = self.memory["command"]
        if isinstance(command, ScheduledStart):
            self.memory["rapp"], self.memory["params"] = command.schedule.rapp, dict(command.schedule.params)
            if self.core.scheduler.too_late(command):
                self.memory["missed"] = True
                await self.core.scheduler.missed(command.schedule, command.due, "the robot was busy until too late")
                raise RuntimeError("scheduled task missed")
            return True
        if isinstance(command, HeardUtterance):
            if command.too_long:
                await self.core.tell_user("Sorry, I did not understand: that was too long for a command.",
                                          speak=self.core.apology_aloud())
                raise RuntimeError("utterance too long")
            rapp = await self.core.spot_keyword(command)
        else:
            rapp = self.core.keyword_rapp(command)
        if rapp is not None:
            self.memory["rapp"], self.memory["params"] = rapp, {}
        return rapp is not None


class Interpret(CoreState):  # s4b: anything else -> the Platform (speech recognition, interpretation)
    async def action(self):
        text = self.memory["command"]
        heard = isinstance(text, HeardUtterance)
        if heard:
            try:
                text = await self.core.recognise_sentence(text)
            except RequestError as e:
                await self.core.tell_user(f"Sorry, I did not understand: {e.reason}", speak=self.core.apology_aloud())
                raise
            if not text:
                await self.core.tell_user("Sorry, I did not understand.", speak=self.core.apology_aloud())
                raise RuntimeError("nothing recognised")
        try:
            found = await self.core.interpret(text)
        except RequestError as e:  # the Platform's reason names the command ("I did not understand ...")
            await self.core.tell_user(f"Sorry, {e.reason}" if "understand" in e.reason
                                      else f"Sorry, I did not understand \"{text}\": {e.reason}",
                                      speak=not heard or self.core.apology_aloud())
            raise
        except Exception as e:  # any failure reaches the user as one sentence
            await self.core.tell_user(f"Sorry, I could not interpret \"{text}\": {_why(e)}")
            raise
        self.memory["rapp"], self.memory["params"] = found.rapp, dict(found.parameters)
        self.memory["schedule"] = found.schedule
        if found.schedule is not None:
            self.memory["text"] = text


class Schedule(CoreState):  # s4c (sec. 7's trigger): keep, cancel or list schedules; the owner is told
    async def action(self):
        # heard by voice: a new schedule is kept only when the owner says yes (agents/core_confirm.py)
        heard = isinstance(self.memory["command"], HeardUtterance)
        await self.core.scheduler.handle(self.memory["schedule"], self.memory["rapp"], self.memory["params"],
                                         self.memory["text"], confirm=self.core.confirmation.ask if heard else None)
        self.core.command_answered()


class Download(CoreState):  # s5: fetch the package, check sha256 and signature
    async def action(self):
        try:
            self.memory["package"] = await self.core.fetch_package(self.memory["rapp"])
        except Exception as e:
            await self.core.tell_user(f"I could not get the application {self.memory['rapp']}: {_why(e)}")
            raise


class Activate(CoreState):  # s6: unpack, spawn a_dyn, hand over supervision
    async def action(self):
        try:
            await self.core.start_dynamic(self.memory["package"], self.memory.get("params", {}))
        except Exception as e:
            if self.core.dynamic is None:  # else s10 tells, once its process is gone
                await self.core.tell_user(f"The application {self.memory['rapp']} did not start: {_why(e)}")
            raise


class Serve(CoreState):  # s8 (+ s9 in the command server): until a_dyn ends in any way
    async def action(self):
        return await self.core.serve_until_done()


class Destroy(CoreState):  # s10: reap a_dyn and its Cloud Agents, resume supervision
    async def action(self):
        await self.core.destroy_dynamic()


def build_core_fsm() -> FSM:
    fsm = FSM("core", initial="s0_init", idle_limit=None)
    for name, state in [("s0_init", Init("init")), ("s1_register", Register("register")),
                        ("s2_vocabulary", Vocabulary("vocabulary")), ("s3_listen", Listen("listen")),
                        ("s4a_keyword", Keyword("keyword")), ("s4b_platform", Interpret("interpret")),
                        ("s4c_schedule", Schedule("schedule")),
                        ("s5_download", Download("download")),
                        ("s6_activate", Activate("activate")), ("s8_serve", Serve("serve")),
                        ("s10_destroy", Destroy("destroy"))]:
        fsm.add_state(name, state)
    fsm.add_transition("s0_init", "s1_register")
    fsm.add_transition("s1_register", "s2_vocabulary")
    fsm.add_transition("s2_vocabulary", "s3_listen")
    fsm.add_transition("s2_vocabulary", "s1_register", on_error=True)
    fsm.add_transition("s3_listen", "s4a_keyword")
    fsm.add_transition("s3_listen", "s3_listen", on_error=True)
    fsm.add_transition("s4a_keyword", "s5_download", when=lambda m, o: bool(o.value))
    fsm.add_transition("s4a_keyword", "s4b_platform", when=lambda m, o: not o.value)
    fsm.add_transition("s4a_keyword", "s3_listen", on_error=True)
    fsm.add_transition("s4b_platform", "s5_download", when=lambda m, o: m.get("schedule") is None)
    fsm.add_transition("s4b_platform", "s4c_schedule", when=lambda m, o: m.get("schedule") is not None)
    fsm.add_transition("s4c_schedule", "s3_listen")
    fsm.add_transition("s4c_schedule", "s3_listen", on_error=True)
    fsm.add_transition("s4b_platform", "s3_listen", on_error=True)
    fsm.add_transition("s5_download", "s6_activate")
    fsm.add_transition("s5_download", "s3_listen", on_error=True)
    fsm.add_transition("s6_activate", "s8_serve")
    fsm.add_transition("s6_activate", "s10_destroy", on_error=True)
    fsm.add_transition("s8_serve", "s10_destroy")
    fsm.add_transition("s8_serve", "s10_destroy", on_error=True)
    fsm.add_transition("s10_destroy", "s3_listen")
    fsm.add_transition("s10_destroy", "s3_listen", on_error=True)
    return fsm


# -- s9: one robot-API request of the Dynamic Agent (agents/core_commands.py holds the steps) -----
class CommandStep(OneShot):
    """One step of s9: `await steps.command_<step>(memory)` (steps: memory["steps"], the Core's
    RobotCommands), whose value picks the next state. An exception is kept (memory["raised"]) for
    the command server: its type says refuse or failure."""

    def __init__(self, step: str):
        super().__init__(step)
        self.step = step

    async def action(self):
        try:
            return await getattr(self.memory["steps"], f"command_{self.step}")(self.memory)
        except Exception as e:
            self.memory["raised"] = e
            raise


def build_command_fsm(action: str) -> FSM:
    fsm = FSM("core.s9", initial="resources" if action in ("lock_resource", "free_resource") else "lock")
    for name, final in [("resources", True), ("lock", False), ("act", False), ("held", False), ("release", True)]:
        fsm.add_state(name, CommandStep(name), final=final)
    fsm.add_transition("lock", "act")
    fsm.add_transition("act", "release", when=lambda m, o: o.value == "done")
    fsm.add_transition("act", "held", when=lambda m, o: o.value == "held")
    fsm.add_transition("held", "act")
    return fsm


def _why(e: BaseException) -> str:
    return str(e) or type(e).__name__
