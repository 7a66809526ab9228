"""The FSMs of a run, drawn from its trace's state records (`rapp trace show FILE --view fsm`,
`rapp trace export FILE --format states`): for each agent, the path of its own FSM (the Core's
fig. 5, the Platform's fig. 6, a RApp's task) with each transition taken and how often, and the
passes of its request FSMs (the Platform's s1 -> sX -> s1 per request, the Core's s9 per robot
command), grouped by the path they took."""
from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable

from ontology.trace import RecordKind

from .trace_report import display_names, mermaid_escape


def _states(records: Iterable[dict]) -> list[dict]:
    return sorted((r for r in records if r.get("kind") == RecordKind.STATE and r.get("event") == "enter"),
                  key=lambda r: r.get("t", 0))


def fsm_paths(records: Iterable[dict]) -> dict:
    """{agent: {"own": {fsm: [state, ...]}, "passes": Counter(pass path -> count)}}. A pass path is
    its states as entered, a sub-FSM's in brackets: "s5_create_cloud[download > build > start]"."""
    out: dict = defaultdict(lambda: {"own": defaultdict(list), "passes": Counter()})
    passes: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in _states(records):
        agent = str(r.get("agent", ""))
        if r.get("conversation_id"):
            passes[(agent, r["conversation_id"])].append(r)
        else:
            out[agent]["own"][str(r.get("fsm", ""))].append(str(r.get("state", "")))
    for (agent, _), recs in passes.items():
        out[agent]["passes"][_pass_path(recs)] += 1
    return out


def _pass_path(recs: list[dict]) -> str:
    top = str(recs[0].get("fsm", ""))
    parts: list[str] = []
    sub: list[str] = []
    for r in recs:
        if r.get("fsm") == top:
            if sub:
                parts[-1] += f"[{' > '.join(sub)}]"
                sub = []
            parts.append(str(r.get("state")))
        else:
            sub.append(str(r.get("state")))
    if sub and parts:
        parts[-1] += f"[{' > '.join(sub)}]"
    return f"{top}: {' > '.join(parts)}"


def transitions(path: list[str]) -> Counter:
    return Counter(zip(path, path[1:]))


def fsm_text(records: Iterable[dict], limit: int = 12) -> str:
    """Each agent's FSMs: its own FSM's path (a long one as its transitions with counts) and its
    request passes by path, most frequent first."""
    records = list(records)
    paths = fsm_paths(records)
    if not paths:
        return "(no state records)"
    names = display_names(paths)
    lines = []
    for agent in sorted(paths, key=lambda a: names.get(a, a)):
        lines.append(f"{names.get(agent, agent)}:")
        for fsm, path in paths[agent]["own"].items():
            if len(path) <= limit:
                lines.append(f"  {fsm}: {' -> '.join(path)}")
            else:
                taken = ", ".join(f"{a} -> {b} x{n}" for (a, b), n in transitions(path).most_common())
                lines.append(f"  {fsm} ({len(path)} states entered): {taken}")
        counted = paths[agent]["passes"]
        if counted:
            lines.append(f"  request passes ({sum(counted.values())}):")
            lines += [f"    {n:5d}  {p}" for p, n in counted.most_common(limit)]
            if len(counted) > limit:
                lines.append(f"    ... {len(counted) - limit} more paths")
    return "\n".join(lines)


def fsm_mermaid(records: Iterable[dict]) -> str:
    """A Mermaid `stateDiagram-v2` per agent's own FSM: every transition taken, with its count."""
    paths = fsm_paths(list(records))
    names = display_names(paths)
    out = ["stateDiagram-v2"]
    for agent in sorted(paths, key=lambda a: names.get(a, a)):
        for fsm, path in paths[agent]["own"].items():
            who = f"{names.get(agent, agent)}_{fsm}".replace("-", "_").replace(".", "_")
            out.append(f"    state {who} {{")
            out.append(f"        [*] --> {who}__{path[0]}")
            for (a, b), n in transitions(path).items():
                out.append(f"        {who}__{a} --> {who}__{b}: {mermaid_escape(f'x{n}')}")
            out.append("    }")
    return "\n".join(out) + "\n"
