"""Smoke test of `python -m bench`: the runner with tiny sizes writes one JSON entry per metric
with the agreed fields (the numbers themselves are not checked here)."""
from __future__ import annotations

import json

import pytest

from bench import common, runner

FIELDS = {"name", "value", "unit", "floor", "ratio", "n"}


def test_table_and_selection():
    m = common.metric("x", 2.0, "ms", 1.0, 2.0, 3, samples=[1.0, 2.0, 3.0], length_ratio=1.01)
    assert FIELDS | {"median", "p95", "length_ratio"} <= set(m) and m["median"] == 2.0
    text = common.table([m])
    assert text.splitlines()[0].split(" | ")[0].strip() == "name" and "ms" in text
    assert runner.select(["robot_rtt", "plan_astar", "rtt"]) == ["rtt", "planning"]
    with pytest.raises(SystemExit):
        runner.select(["nonsense"])


@pytest.mark.slow  # 60 s: `rapp bench --quick` runs the same
def test_runner_tiny_json_shape(tmp_path, capsys):
    out = tmp_path / "bench.json"
    code = runner.main(["--quick", "--tiny", "--json", str(out),
                        "--only", "rtt", "messages", "planning", "sim_rtf"])
    doc = json.loads(out.read_text())
    metrics = doc["metrics"]
    assert code == 0, [m.get("error") for m in metrics]
    assert doc["machine"]["nproc"] >= 1 and doc["mode"] == "tiny"
    names = {m["name"] for m in metrics}
    assert {"robot_rtt", "platform_rtt", "messages", "messages_traced", "plan_astar", "sim_rtf_1"} <= names
    for m in metrics:
        assert FIELDS <= set(m), m
        assert m["value"] is not None and m["floor"] is not None and m["ratio"] is not None, m
    rtt = next(m for m in metrics if m["name"] == "robot_rtt")
    assert rtt["n"] == 20 and rtt["p95"] >= rtt["median"] > 0
    assert all("length_ratio" in m for m in metrics if m["name"].startswith("plan_"))
    printed = capsys.readouterr().out
    assert "robot_rtt" in printed
    # the goals are judged and printed next to the table
    assert rtt["goal"] == "ratio <= 1.3" and rtt["goal_met"] == (rtt["ratio"] <= 1.3)
    assert f"goal robot_rtt: ratio <= 1.3: {'met' if rtt['goal_met'] else 'NOT met'}" in printed
    astar = next(m for m in metrics if m["name"] == "plan_astar")
    assert astar["goal_met"] == (astar["ratio"] <= 1.0 and astar["length_ratio"] <= 1.02)


@pytest.mark.slow  # a whole hazard run (~25 s): tests/test_hazard_scenario.py runs one by default
def test_runner_tiny_fleet(tmp_path):
    out = tmp_path / "bench.json"
    code = runner.main(["--quick", "--tiny", "--json", str(out), "--only", "fleet"])
    metrics = json.loads(out.read_text())["metrics"]
    assert code == 0, [m.get("error") for m in metrics]
    for m in metrics:
        assert FIELDS <= set(m), m
        assert m["value"] is not None and m["floor"] is not None and m["ratio"] is not None, m
    # one robot ran the hazard-detection RApp through the lifecycle; judged against the size asked
    # (tiny: 1; quick: 4; full: 20)
    fleet = next(m for m in metrics if m["name"] == "fleet")
    assert (fleet["value"], fleet["rapp"], fleet["all_correct_at_n"]) == (1, "hazard-detection", 1)
    assert fleet["floor"] == 1 and fleet["goal_met"] is True
    assert [n for n, _ in fleet["heartbeats_late_by_round"]] == [1]  # counted per round (0 expected when quiet)
    assert next(m for m in metrics if m["name"] == "fleet_service_p95")["n"] > 0


@pytest.mark.slow  # 25 s and a 2 s bound the suite's own load breaks: `python -m bench --only recovery` measures it
def test_recovery_tiny(tmp_path):
    """Faults injected from outside (SIGKILL, a hang, a server restart): every recovery metric is
    measured and judged against the issue's goal; the test allows twice the goal for a loaded CI
    machine (the benchmark itself judges the exact goal)."""
    out = tmp_path / "bench.json"
    code = runner.main(["--tiny", "--json", str(out), "--only", "recovery"])
    metrics = {m["name"]: m for m in json.loads(out.read_text())["metrics"]}
    assert code == 0, [m.get("error") for m in metrics.values()]
    limits = {"recovery_killed_told": 1000, "recovery_hung_back": 2000, "recovery_reconnect": 2000,
              "recovery_command_answered": 500}
    assert set(limits) <= set(metrics)
    for name, goal in limits.items():
        m = metrics[name]
        assert FIELDS <= set(m) and m["floor"] > 0 and "goal_met" in m, m
        assert 0 <= m["value"] <= 2 * goal, m
    # a hang is seen only as missing heartbeats: never sooner than the Core's timeout after the last beat,
    # which may come up to one beat period before the hang's state is entered
    from agents.dynamic_agent import HEARTBEAT_S
    assert metrics["recovery_hung_back"]["value"] >= metrics["recovery_hung_back"]["floor"] - HEARTBEAT_S * 1e3


@pytest.mark.slow  # 10 s; `python -m bench --only estop` measures it
async def test_estop_latency_tiny():
    """The owner's "stop" halts a RApp-driven base within the goal (twice it, for a loaded CI machine);
    the floor is the same message's delivery, so the stop cannot be faster than it."""
    from bench import estop
    [m] = await estop.run(n=2)
    assert FIELDS <= set(m) and m["n"] == 2, m
    assert 0 < m["floor"] <= m["value"] <= 2 * estop.GOAL_MS, m


def test_the_fleet_p95_is_judged_only_at_the_goals_size():
    """A fleet that failed below its goal keeps the p95 of its last passing size (one robot: ratio 1),
    which must not read as the goal met."""
    from bench.runner import goal_lines

    below = {"name": "fleet_service_p95", "value": 50.0, "ratio": 1.0, "at_n": 1, "goal_n": 20}
    at_goal = dict(below, at_n=20, ratio=2.5)
    too_slow = dict(at_goal, ratio=3.5)
    goal_lines([below, at_goal, too_slow])
    assert [m["goal_met"] for m in (below, at_goal, too_slow)] == [False, True, False]


def test_a_failed_fleet_rounds_trace_is_kept(tmp_path):
    """The fleet's run directory is temporary: a failed round's trace is copied out first."""
    from bench.fleet import keep_trace

    trace = tmp_path / "run" / "trace.jsonl"
    trace.parent.mkdir()
    trace.write_text('{"t": 1.0, "kind": "message"}\n')
    kept = keep_trace(trace, tmp_path)
    trace.unlink()
    assert kept.parent == tmp_path and kept.name.startswith("bench-fleet-failed-")
    assert kept.read_text() == '{"t": 1.0, "kind": "message"}\n'


def test_a_call_failed_by_its_cloud_agents_crash_is_not_lost():
    """The fleet's check: a request without an answer is lost, unless its Dynamic Agent was told
    afterwards that the Cloud Agent it called had died (its calls in flight fail, said so)."""
    from bench.fleet import request_latencies

    dyn, cloud, platform = "dyn-nao1-x@localhost", "cloud-x@localhost", "platform@localhost"

    def msg(t, direction, conv, performative, receiver, action="observe"):
        return {"t": t, "kind": "message", "agent": dyn, "dir": direction, "performative": performative,
                "conversation_id": conv, "receiver": receiver, "action": action, "ontology": "cloud"}

    trace = [msg(1.0, "send", "a", "request", platform, "home_get_info"),
             msg(1.1, "recv", "a", "inform", dyn, "home_get_info"),
             msg(2.0, "send", "b", "request", cloud),  # in flight when the Cloud Agent died
             {"t": 2.5, "kind": "structure", "event": "cloud-down", "agent": dyn, "cloud": cloud},
             msg(3.0, "send", "c", "request", cloud),  # to the restarted one, which died too
             {"t": 3.5, "kind": "structure", "event": "cloud-down", "agent": dyn, "cloud": cloud},
             msg(4.0, "send", "e", "request", cloud, "solve_pose")]  # after both: nobody ever said why
    lat, missing = request_latencies(trace, 0.0, platform)
    assert lat["failed_by_crash"] == ["dyn-nao1-x:observe"] * 2  # b and c
    assert missing == ["dyn-nao1-x:solve_pose"] and len(lat["platform"]) == 1
