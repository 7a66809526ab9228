"""Fig. 6 (the Platform's FSM) and fig. 5's s9 as built: the graph the module draws is the one the
code runs, every action the Platform serves lands in one of the figure's states, and s9's steps
exist on the Core (the lifecycle test watches both in a real run's trace)."""
from __future__ import annotations

import ontology.services  # noqa: F401 - registers the service models
from agents.core_commands import RobotCommands
from agents.core_fsm import build_command_fsm, build_core_fsm
from agents.platform_agent import PlatformAgent
from agents.platform_fsm import GRAPH, build_platform_fsm, build_request_fsm, route
from agents.services import SERVICES
from agents import platform_directory as D
from ontology import platform as P
from ontology.registry import actions
from ontology.robot_actions import facts


def edges(fsm) -> set[tuple[str, str]]:
    return {(t.source, t.target) for t in fsm.transitions}


def test_the_platform_fsm_is_the_figures_graph():
    own = build_platform_fsm()
    own.validate()
    assert edges(own) == {("s0_init", "s1_wait")} and own.finals == {"s1_wait"}
    for state in GRAPH["s1_wait"]:
        one = build_request_fsm(state)
        one.validate()
        assert one.initial == state and one.finals == {state} and GRAPH[state] == ["s1_wait"]
    s5 = build_request_fsm("s5_create_cloud").states["s5_create_cloud"]
    assert s5.initial == "download" and edges(s5) == {("download", "build"), ("build", "start")}
    s4 = build_request_fsm("s4_service").states["s4_service"]
    assert edges(s4) == {("admit", "execute")}


def test_every_platform_action_has_its_state_and_each_step_its_method():
    served = set(actions(P.ONTOLOGY)) | set(actions(D.ONTOLOGY))
    routed = {a: route(a, by_core=False) for a in served}
    assert set(routed.values()) <= set(GRAPH["s1_wait"])
    assert routed["start_cloud_agent"] == "s5_create_cloud" and routed["stop_cloud_agent"] == "s6_destroy_cloud"
    assert routed["login"] == "s2_register" and routed["interpret_command"] == "s3_interpret"
    assert all(routed[s] == "s4_service" for s in SERVICES if s != "interpret_command"
               and s != "speech_recognition"), routed
    # a Core's recording is its command (s3); a RApp's is a service like any other (s4)
    assert route("speech_recognition", by_core=True) == "s3_interpret"
    assert route("speech_recognition", by_core=False) == "s4_service"
    for state in GRAPH["s1_wait"]:
        for step in _steps(build_request_fsm(state)):
            assert callable(getattr(PlatformAgent, step.method)), step.method


def test_s9_is_a_sub_fsm_of_the_core_with_a_hold_for_the_emergency_stop():
    assert "s9" not in build_core_fsm().states  # s9 is not a state of the Core's own pass: it runs beside s8
    move = build_command_fsm("move_to")
    move.validate()
    assert move.initial == "lock" and edges(move) == {("lock", "act"), ("act", "release"), ("act", "held"),
                                                      ("held", "act")}
    assert build_command_fsm("lock_resource").initial == "resources"
    for name in move.states:
        assert callable(getattr(RobotCommands, f"command_{name}"))
    assert facts("move_to").motion and not facts("get_global_pose").motion


def _steps(fsm):
    for b in fsm.states.values():
        if hasattr(b, "states"):
            yield from _steps(b)
        else:
            yield b
