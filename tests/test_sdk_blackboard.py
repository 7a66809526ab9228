"""The SDK's typed blackboard, log and progress: declared keys, types, writers, traced writes."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from behaviours import FSM
from ontology.services.common import Pose2D
from ontology.trace import RecordKind, is_valid
from rapps.sdk import Blackboard, BlackboardError, Key, Step, Task


def board(writer="plan"):
    traced = []
    bb = Blackboard({"goal": Key(Pose2D, writers=["plan"]), "visited": Key(list[str], default=[])}, {},
                    writer=lambda: writer, trace=lambda kind, **f: traced.append((kind, f)))
    return bb, traced


def test_declared_keys_are_typed_and_traced():
    bb, traced = board()
    bb.goal = {"x": 1, "y": 2, "theta": 0}  # validated into the declared type
    assert bb.goal == Pose2D(x=1, y=2, theta=0) and bb.visited == []
    assert traced == [(RecordKind.BLACKBOARD, {"key": "goal", "value": repr(bb.goal), "writer": "plan"})]
    with pytest.raises(TypeError, match="blackboard key 'visited' takes"):
        bb.visited = [{"not": "a string"}]


def test_undeclared_unwritten_and_foreign_writes_are_errors_naming_the_key():
    bb, _ = board(writer="look")
    with pytest.raises(BlackboardError, match="'path' is not declared .*goal, visited"):
        bb.path
    with pytest.raises(BlackboardError, match="'goal' has not been written yet"):
        bb.goal
    with pytest.raises(BlackboardError, match="state 'look' may not write blackboard key 'goal'"):
        bb.goal = Pose2D(x=0, y=0, theta=0)
    bb.visited = ["kitchen"]  # no writers declared: any state


class Runtime(SimpleNamespace):
    """The parts of a Dynamic Agent a Task reads (the transport is tested elsewhere)."""


async def test_log_progress_and_blackboard_writes_name_the_running_state(tmp_path):
    records = []
    tracer = SimpleNamespace(record=lambda kind, **f: records.append({"t": 0.0, "pid": 1, "kind": kind, **f}))
    manifest = SimpleNamespace(name="demo", version="1.0.0")
    runtime = Runtime(params={}, manifest=manifest, robot_info=None, core="core", platform="platform", token="t",
                      memory={}, tracer=tracer, address="dyn@localhost", package_dir=str(tmp_path / "package"))

    class Demo(Task):
        keys = {"n": Key(int, writers=["count"])}

        def build(self):
            fsm = FSM("demo", initial="count")
            fsm.add_state("count", Step(self.count), final=True)
            return fsm

        async def count(self, memory):
            self.bb.n = 3
            self.log.info("counted %d", self.bb.n)
            self.progress(0.5, "half")
            (self.outputs / "n.txt").write_text("3")

    task = Demo(runtime)
    task.root = task.build()
    assert (await task.root.run()).ok and runtime.memory["n"] == 3  # `memory` is the untyped view
    kinds = [r["kind"] for r in records if r["kind"] != "state"]
    assert kinds == [RecordKind.BLACKBOARD, RecordKind.LOG, RecordKind.PROGRESS]
    log = next(r for r in records if r["kind"] == RecordKind.LOG)
    assert (log["message"], log["state"], log["level"]) == ("counted 3", "count", "info")
    assert all(is_valid(r) for r in records)
    assert (tmp_path / "outputs" / "n.txt").read_text() == "3"
    with pytest.raises(ValueError):
        task.progress(1.5)
