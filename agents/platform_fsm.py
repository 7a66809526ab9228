"""The Platform Agent's FSM, as in fig. 6 of paper 000, on one screen.

    s0 init -> s1 wait for a request -+-> s2 register          (users, a Core's robot, tokens)       -> s1
                                      +-> s3 interpret         (a Core's long command, sec. 5.1)     -> s1
                                      +-> s4 service           (sub-FSM: admit -> execute)           -> s1
                                      +-> s5 create a_cloud    (sub-FSM: download -> build -> start) -> s1
                                      +-> s6 destroy a_cloud                                         -> s1

What each state does is the paper's text: the Platform registers users and the Cores of robots
(sec. 5.5), interprets the long commands a Core records (sec. 5.1), presents its computation as
services (sec. 5.3, each a sub-FSM here as the Core's s9 is), creates a Cloud Agent on a Dynamic
Agent's prompt by downloading it from the Store, building it and starting it (fig. 4a, sec. 6.5),
and destroys it when the Dynamic Agent says it is no longer needed (sec. 4).

How the model maps onto a Platform serving many robots at once: the agent's own FSM (`platform`)
goes s0 -> s1 and stays in s1 as long as it serves. Each request is one pass s1 -> sX -> s1 of its
own instance of the request FSM, run by the responder as the request comes (`Responder(concurrent=
True)`): passes run side by side, so one robot's path planning never waits for another's Cloud Agent
to start. A request is taken in s1 only when its token holds (the responder's check, before sX);
sX is chosen by the request's action (`route`). Every state entered is a trace record (kind
"state", `fsm` "platform" or "platform.s4_service" / "platform.s5_create_cloud" for the sub-FSMs'
states, with the request's `conversation_id`); `rapp trace show FILE --view fsm` draws them.

A replica Platform (agents/platform_directory.py, not in the paper) runs the same FSM for what it
serves (s4, and s2 for a revoked token); what only the primary serves is refused on arrival.
"""
from __future__ import annotations

import asyncio

from behaviours import FSM, Behaviour, OneShot

PLATFORM_FSM = "platform"

# s1 -> the state that serves the request, by its action (every other action: s4, a service)
REGISTER = frozenset({"register_user", "login", "register_robot", "issue_app_token", "verify_token",
                      "cloud_ready", "platform_report", "list_platforms", "lookup_token", "token_revoked"})
INTERPRET = frozenset({"interpret_command"})
CREATE_CLOUD = frozenset({"start_cloud_agent"})
DESTROY_CLOUD = frozenset({"stop_cloud_agent", "release_cloud_agents"})
# the figure's graph, as drawn above (tests/test_platform_fsm.py holds the built FSMs to it)
GRAPH = {"s0_init": ["s1_wait"],
         "s1_wait": ["s2_register", "s3_interpret", "s4_service", "s5_create_cloud", "s6_destroy_cloud"],
         **{s: ["s1_wait"] for s in ("s2_register", "s3_interpret", "s4_service", "s5_create_cloud",
                                     "s6_destroy_cloud")}}


def route(action: str, by_core: bool) -> str:
    """The state of fig. 6 that serves a request for `action`; `by_core`: the sender holds a login
    token (a Core or a user, not a RApp): its speech recognition is a Core's command (s3)."""
    if action in REGISTER:
        return "s2_register"
    if action in INTERPRET or (action == "speech_recognition" and by_core):
        return "s3_interpret"
    if action in CREATE_CLOUD:
        return "s5_create_cloud"
    if action in DESTROY_CLOUD:
        return "s6_destroy_cloud"
    return "s4_service"


# -- the agent's own FSM: s0 -> s1 ---------------------------------------------------------------
class Init(OneShot):  # s0: users, tokens and service data opened (setup); a crash's leftovers swept
    async def action(self):
        self.agent.platform_init()


class Wait(Behaviour):  # s1: the responders serve each request's pass; here until the agent stops
    async def transition(self):
        await asyncio.get_running_loop().create_future()  # never done: the agent's stop ends it

    def terminal(self):
        return self.iterations >= 1


def build_platform_fsm() -> FSM:
    fsm = FSM(PLATFORM_FSM, initial="s0_init", idle_limit=None)
    fsm.add_state("s0_init", Init("init"))
    fsm.add_state("s1_wait", Wait("wait"), final=True)
    fsm.add_transition("s0_init", "s1_wait")
    return fsm


# -- one request's pass: s1 -> sX -> s1 ----------------------------------------------------------
class Step(OneShot):
    """One step of a request: `await agent.<method>(memory)`; its value, when any, is the reply.
    An exception is kept (memory["raised"]) for the responder: its type says refuse or failure."""

    def __init__(self, name: str, method: str):
        super().__init__(name)
        self.method = method

    async def action(self):
        try:
            reply = await getattr(self.agent, self.method)(self.memory)
        except Exception as e:
            self.memory["raised"] = e
            raise
        if reply is not None:
            self.memory["reply"] = reply


def _sub(name: str, steps: list[tuple[str, str]]) -> FSM:
    fsm = FSM(f"{PLATFORM_FSM}.{name}", initial=steps[0][0])
    for (state, method), nxt in zip(steps, steps[1:] + [None]):
        fsm.add_state(state, Step(state, method), final=nxt is None)
        if nxt is not None:
            fsm.add_transition(state, nxt[0])
    return fsm


def build_request_fsm(state: str) -> FSM:
    """The pass of one request taken in s1, from `state` (route()); the pass ends back in s1, where
    the agent's own FSM is. s4 and s5 are sub-FSMs (the figure's double circles)."""
    states = {
        "s2_register": lambda: Step("register", "serve_request"),
        "s3_interpret": lambda: Step("interpret", "serve_request"),
        "s4_service": lambda: _sub("s4_service", [("admit", "admit_service"), ("execute", "execute_service")]),
        "s5_create_cloud": lambda: _sub("s5_create_cloud", [("download", "cloud_download"),
                                                            ("build", "cloud_build"), ("start", "cloud_start")]),
        "s6_destroy_cloud": lambda: Step("destroy", "serve_request"),
    }
    fsm = FSM(PLATFORM_FSM, initial=state)
    fsm.add_state(state, states[state](), final=True)
    return fsm
