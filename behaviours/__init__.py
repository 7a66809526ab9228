"""Behaviours of embodied agents (paper 002): transition function + terminal and error conditions,
FSMs of behaviours with sub-FSM states and an idle default, behaviour-tree composites and
decorators (tree.py), and a host that runs them in SPADE. See behaviours/example.py for a worked
example."""
from .behaviour import Behaviour, Context, Idle, OneShot, Outcome, Wait, active_path, exception_text
from .fsm import FSM, FSMError
from .host import BehaviourHost
from .pause import PauseGate
from .tree import Inverter, Parallel, Retry, Selector, Sequence, Timeout

__all__ = ["Behaviour", "active_path", "exception_text", "Context", "Idle", "OneShot", "Outcome", "Wait", "FSM", "FSMError",
           "BehaviourHost", "PauseGate", "Sequence", "Selector", "Parallel", "Timeout", "Retry", "Inverter"]
