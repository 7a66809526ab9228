"""The Core Agent's FSM, state by state as in fig. 5 of paper 000.

    s0 init -> s1 register -> s2 vocabulary -> s3 listen -> s4 interpret -> s5 download
      -> s6 activate (spawn a_dyn, hand supervision over) -> s8 serve (s9: the command server
      executes each robot-API request) -> s10 destroy (reap a_dyn, resume supervision) -> s3

A failed interpretation or download tells the user why and returns to s3; a failed activation
goes through s10 so nothing is left running.
"""
from __future__ import annotations

import asyncio
import logging

from behaviours import FSM, Behaviour, OneShot

from .errors import RequestError

log = logging.getLogger("rapp.core")


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


class Interpret(CoreState):  # s4: isolated keyword -> RApp; a sentence -> Platform
    async def action(self):
        text = self.memory["command"]
        try:
            found = await self.core.interpret(text)
        except RequestError as e:  # the Platform's reason names the command ("I did not understand ...")
            await self.core.tell_user(f"Sorry, {e.reason}" if "understand" in e.reason
                                      else f"Sorry, I did not understand \"{text}\": {e.reason}")
            raise
        except Exception as e:  # any failure reaches the user as one sentence
            await self.core.tell_user(f"Sorry, I could not interpret \"{text}\": {_why(e)}")
            raise
        self.memory["rapp"], self.memory["params"] = found.rapp, dict(found.parameters)


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
                        ("s4_interpret", Interpret("interpret")), ("s5_download", Download("download")),
                        ("s6_activate", Activate("activate")), ("s8_serve", Serve("serve")),
                        ("s10_destroy", Destroy("destroy"))]:
        fsm.add_state(name, state)
    fsm.add_transition("s0_init", "s1_register")
    fsm.add_transition("s1_register", "s2_vocabulary")
    fsm.add_transition("s2_vocabulary", "s3_listen")
    fsm.add_transition("s2_vocabulary", "s1_register", on_error=True)
    fsm.add_transition("s3_listen", "s4_interpret")
    fsm.add_transition("s3_listen", "s3_listen", on_error=True)
    fsm.add_transition("s4_interpret", "s5_download")
    fsm.add_transition("s4_interpret", "s3_listen", on_error=True)
    fsm.add_transition("s5_download", "s6_activate")
    fsm.add_transition("s5_download", "s3_listen", on_error=True)
    fsm.add_transition("s6_activate", "s8_serve")
    fsm.add_transition("s6_activate", "s10_destroy", on_error=True)
    fsm.add_transition("s8_serve", "s10_destroy")
    fsm.add_transition("s8_serve", "s10_destroy", on_error=True)
    fsm.add_transition("s10_destroy", "s3_listen")
    fsm.add_transition("s10_destroy", "s3_listen", on_error=True)
    return fsm


def _why(e: BaseException) -> str:
    return str(e) or type(e).__name__
