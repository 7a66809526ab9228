"""Readable views of a run trace (agents/tracing.py): filters, deduplicated messages, a table,
a text sequence diagram, a Mermaid diagram and a summary.

All functions are pure: they take the list of records returned by `agents.tracing.read_trace`
and return new values. Every message is normally traced twice (dir=send by its sender, dir=recv by
its receiver); messages from or to external XMPP clients appear once. `message_events` merges the
pair into one event; the other views are built on `timeline`, which interleaves those events with
the non-message records (structure, agent, behaviour, state, timeout, dropped) in time order.

    python -m scenarios.trace_report TRACE.jsonl [--agent core1] [--conv c-1234] [--mermaid]
"""
from __future__ import annotations

import argparse
import json
from collections import Counter, defaultdict, deque
from collections.abc import Iterable

from agents.tracing import read_trace
from ontology.trace import CHAT, EXPECT_ANSWER, FINAL_ANSWERS, OPENING_OR_CHAT, RecordKind


# -- names ----------------------------------------------------------------------------------------
def bare(jid: str | None) -> str:
    """'core1@localhost/res' -> 'core1@localhost'."""
    return (jid or "").split("/", 1)[0]


def local(jid: str | None) -> str:
    """'core1@localhost/res' -> 'core1'; a name without '@' is returned as is."""
    return bare(jid).split("@", 1)[0]


# the agents' roles, by the account names they run under (a Dynamic or Cloud Agent's name is random)
ROLES = {"core": "core-", "dyn": "dyn-", "cloud": "cloud-", "platform": "platform", "store": "store",
         "owner": "owner-"}


def role(jid: str | None) -> str:
    """The role of an agent ('core', 'dyn', ...), or '' when its name is none of ROLES'."""
    name = local(jid)
    return next((r for r, prefix in ROLES.items()
                 if name == prefix.rstrip("-") or (prefix.endswith("-") and name.startswith(prefix))), "")


def agent_matches(jid: str | None, wanted: str) -> bool:
    """True when `jid` is the agent `wanted`, given as full JID, bare JID, local part or role (ROLES:
    "dyn" is every Dynamic Agent of the trace)."""
    if not jid or not wanted:
        return False
    b, w = bare(jid), bare(wanted)
    return b == w or ("@" not in w and (local(b) == w or (w in ROLES and role(b) == w)))


def short_conv(conversation_id: str | None, n: int = 8) -> str:
    """A short, still recognisable conversation id: 'c-618059c0cba54423' -> '618059c0'."""
    cid = conversation_id or ""
    cid = cid.removeprefix("c-")
    return cid[:n]


def conv_matches(conversation_id: str | None, wanted: str) -> bool:
    """Exact id, a prefix of it, or a prefix of its short form (without 'c-')."""
    cid = conversation_id or ""
    if not cid or not wanted:
        return False
    return cid.startswith(wanted) or (cid.startswith("c-") and cid[2:].startswith(wanted))


def jids_of(rec: dict) -> list[str]:
    """Agents a record is about: sender, receiver, agent, and any other JID-valued field."""
    out = []
    for key in ("agent", "sender", "receiver"):
        if rec.get(key):
            out.append(bare(rec[key]))
    for key, value in rec.items():
        if key not in ("agent", "sender", "receiver", "content", "kind") and isinstance(value, str) \
                and "@" in value and " " not in value:
            out.append(bare(value))
    return list(dict.fromkeys(out))


# -- filtering and deduplication -----------------------------------------------------------------
def filter_records(records: Iterable[dict], agents: Iterable[str] | None = None,
                   conversations: Iterable[str] | None = None) -> list[dict]:
    """Records concerning any of `agents` (sender, receiver, agent or a JID field; bare JID or local
    part) AND belonging to any of `conversations` (id or prefix). With `conversations`, records
    without a conversation id (structure, behaviour...) are left out. None means no filter."""
    agents = [a for a in (agents or []) if a] or None
    conversations = [c for c in (conversations or []) if c] or None
    out = []
    for rec in records:
        if agents and not any(agent_matches(j, a) for j in jids_of(rec) for a in agents):
            continue
        if conversations and not any(conv_matches(rec.get("conversation_id"), c)
                                     for c in conversations):
            continue
        out.append(rec)
    return out


def _message_key(rec: dict) -> tuple:
    """What a send and its recv share; content stands in for a missing message id (plain chat)."""
    mid = rec.get("message_id") or ""
    return (bare(rec.get("sender")), bare(rec.get("receiver")), rec.get("conversation_id") or "",
            mid, rec.get("performative") or "", "" if mid else rec.get("content") or "")


def message_events(records: Iterable[dict]) -> list[dict]:
    """One event per message, in time order. An event holds the message fields (of the send record
    when there is one) plus: t (send time, else receive time), send_t, recv_t, latency (recv_t -
    send_t or None), seen ('both', 'send' or 'recv'), path (delivery path). Send/recv records are
    paired by message id (FIFO per sender, receiver, conversation, performative, content when the
    id is empty), whichever of the two was written first."""
    events: list[dict] = []
    waiting: dict[tuple, dict[str, deque]] = defaultdict(lambda: {"send": deque(), "recv": deque()})
    for rec in sorted((r for r in records if r.get("kind") == RecordKind.MESSAGE), key=lambda r: r.get("t", 0)):
        direction = "recv" if rec.get("dir") == "recv" else "send"
        other = "send" if direction == "recv" else "recv"
        queues = waiting[_message_key(rec)]
        if queues[other]:
            ev = queues[other].popleft()
            _merge(ev, rec, direction)
            continue
        ev = {k: v for k, v in rec.items() if k not in ("dir", "agent", "pid")}
        ev.update(kind=RecordKind.MESSAGE.value, sender=bare(rec.get("sender")), receiver=bare(rec.get("receiver")),
                  send_t=None, recv_t=None, latency=None, seen=direction)
        ev[f"{direction}_t"] = rec.get("t")
        queues[direction].append(ev)
        events.append(ev)
    events.sort(key=lambda e: e.get("t", 0))
    return events


def _merge(ev: dict, rec: dict, direction: str) -> None:
    ev[f"{direction}_t"] = rec.get("t")
    ev["seen"] = "both"
    if direction == "send":  # the send record is authoritative for fields and time
        ev.update({k: v for k, v in rec.items() if k not in ("dir", "agent", "pid")})
        ev["sender"], ev["receiver"] = bare(rec.get("sender")), bare(rec.get("receiver"))
    ev["t"] = ev["send_t"]
    ev["latency"] = round(ev["recv_t"] - ev["send_t"], 6)
    if ev.get("path") != rec.get("path") and rec.get("path"):
        ev["path"] = ev.get("path") or rec.get("path")


def timeline(records: Iterable[dict]) -> list[dict]:
    """Deduplicated message events and non-message records, in time order."""
    records = list(records)
    items = message_events(records) + [r for r in records if r.get("kind") != RecordKind.MESSAGE]
    items.sort(key=lambda r: r.get("t", 0))
    return items


def participants(items: Iterable[dict]) -> list[str]:
    """Bare JIDs in order of first appearance (senders before receivers)."""
    return list(dict.fromkeys(j for it in items for j in jids_of(it)))


def display_names(jids: Iterable[str]) -> dict[str, str]:
    """Bare JID -> local part, or the bare JID where two agents share a local part."""
    jids = list(dict.fromkeys(jids))
    counts = Counter(local(j) for j in jids)
    return {j: local(j) if counts[local(j)] == 1 else j for j in jids}


# -- labels -------------------------------------------------------------------------------------
def message_label(ev: dict) -> str:
    """'request move_to', 'inform move_to', 'chat'."""
    return " ".join(x for x in (ev.get("performative") or CHAT, ev.get("action") or "") if x)


def note_label(rec: dict, names: dict[str, str] | None = None) -> str:
    """One-line description of a non-message record, e.g. 'spawn dyn-hazard@localhost by core1'."""
    names = names or {}

    def name(jid: str | None) -> str:
        return names.get(bare(jid), local(jid))

    kind, event, agent = rec.get("kind", ""), rec.get("event", ""), rec.get("agent", "")
    skip = {"t", "kind", "pid", "event", "agent", "cls"}
    if kind == RecordKind.BEHAVIOUR:
        return f"{rec.get('behaviour', '?')} {event} on {name(agent)}"
    if kind == RecordKind.AGENT:
        return f"{name(agent)} {event}" + (f" ({rec['reason']})" if rec.get("reason") else "")
    if kind == RecordKind.STATE:
        return f"{name(agent)} {rec.get('fsm', '')} -> {rec.get('state', '')}"
    if kind == RecordKind.TIMEOUT:
        return f"timeout {name(agent)} waiting {rec.get('action', '')} from {name(rec.get('peer'))}"
    if kind == RecordKind.DROPPED:
        return f"dropped by {name(agent)}: {rec.get('performative', '')} from {name(rec.get('sender'))}"
    fields = {k: v for k, v in rec.items() if k not in skip}
    subject = next((k for k, v in fields.items() if isinstance(v, str) and "@" in v), None)
    head = f"{event or kind} {fields.pop(subject)}" if subject else event or kind
    by = [f"by {name(agent)}"] if agent else []
    return " ".join([head] + by + [f"{k}={_short(v)}" for k, v in fields.items()])


def _short(value, n: int = 40) -> str:
    text = value if isinstance(value, str) else json.dumps(value, default=str)
    return text if len(text) <= n else text[: n - 1] + "…"


def _ms(t: float | None, t0: float) -> str:
    return "" if t is None else f"{(t - t0) * 1000:.1f}"


# -- views ---------------------------------------------------------------------------------------
def table(records: Iterable[dict]) -> str:
    """Fixed-width table, one line per message (relative ms, sender → receiver as local names,
    performative, action, short conversation id, path, size, latency ms) and one
    '== event ... ==' line per structure/agent/behaviour/state/timeout/dropped record."""
    items = timeline(records)
    if not items:
        return "(empty trace)"
    t0 = items[0].get("t", 0)
    names = display_names(participants(items))
    width = max([len(n) for n in names.values()] + [6])
    head = (f"{'ms':>9}  {'sender':<{width}}   {'receiver':<{width}}  {'performative':<14} "
            f"{'action':<18} {'conv':<8} {'path':<6} {'size':>6} {'lat ms':>7}")
    lines = [head, "-" * len(head)]
    for it in items:
        if it.get("kind") == RecordKind.MESSAGE:
            lat = "" if it["latency"] is None else f"{it['latency'] * 1000:.1f}"
            path = (it.get("path") or "") + ("" if it["seen"] == "both" else f"({it['seen']})")
            lines.append(
                f"{_ms(it.get('t'), t0):>9}  {names.get(it['sender'], it['sender']):<{width}} → "
                f"{names.get(it['receiver'], it['receiver']):<{width}}  "
                f"{it.get('performative') or CHAT:<14} {_short(it.get('action') or '', 18):<18} "
                f"{short_conv(it.get('conversation_id')):<8} {path:<6} {it.get('size', ''):>6} {lat:>7}")
        else:
            lines.append(f"{_ms(it.get('t'), t0):>9}  == {note_label(it, names)} ==")
    return "\n".join(lines)


def sequence_text(records: Iterable[dict], col_width: int | None = None) -> str:
    """Plain-text sequence diagram: one column (lifeline '|') per agent, a label line and an
    arrow line per message, full-width '== ... ==' notes for the other records; left gutter
    holds the relative time in ms."""
    items = timeline(records)
    if not items:
        return "(empty trace)"
    t0 = items[0].get("t", 0)
    jids = participants(it for it in items if it.get("kind") == RecordKind.MESSAGE) or participants(items)
    names = display_names(jids)
    width = col_width or max([len(n) for n in names.values()] + [10]) + 4
    gutter = 10
    x = {j: gutter + i * width + width // 2 for i, j in enumerate(jids)}
    total = gutter + width * len(jids)

    def blank() -> list[str]:
        row = [" "] * total
        for pos in x.values():
            row[pos] = "|"
        return row

    header = [" "] * total
    for j, pos in x.items():
        start = max(0, pos - len(names[j]) // 2)
        header[start:start + len(names[j])] = names[j]
    lines = ["".join(header).rstrip(), "".join(blank()).rstrip()]
    for it in items:
        stamp = _ms(it.get("t"), t0).rjust(gutter - 2) + "  "
        if it.get("kind") != RecordKind.MESSAGE:
            lines.append(stamp + f"== {note_label(it, names)} ==")
            continue
        a, b = x.get(it["sender"]), x.get(it["receiver"])
        label = message_label(it) + ("" if it["seen"] == "both" else f" [{it['seen']} only]")
        if a is None or b is None:
            lines.append(stamp + f"{it['sender']} -> {it['receiver']}: {label}")
            continue
        top, arrow = blank(), blank()
        lo, hi = min(a, b), max(a, b)
        if a == b:
            arrow[a + 1:a + 4] = "--'"
            start = a + 5
        else:
            arrow[lo + 1:hi] = "-" * (hi - lo - 1)
            arrow[hi - 1 if b > a else lo + 1] = ">" if b > a else "<"
            start = lo + 2
        text = label[: max(total - start, 8)]
        top[start:start + len(text)] = text
        lines.append(" " * gutter + "".join(top)[gutter:].rstrip())
        lines.append(stamp + "".join(arrow)[gutter:].rstrip())
    return "\n".join(lines)


def mermaid_escape(text: str) -> str:
    """Text safe inside a Mermaid sequence message or note (entity codes for # ; < > " and no
    newlines or comment markers)."""
    codes = {"#": "#35;", ";": "#59;", "<": "#lt;", ">": "#gt;", '"': "#quot;", "%": "#37;",
             "{": "#123;", "}": "#125;"}
    return " ".join("".join(codes.get(ch, ch) for ch in str(text)).split())


def mermaid(records: Iterable[dict]) -> str:
    """Mermaid `sequenceDiagram`: one participant per agent (alias = local name), `A->>B: request
    move_to` for opening messages, `A-->>B:` for answers, `Note over A: ...` for other records."""
    items = timeline(records)
    jids = participants(items)
    names = display_names(jids)
    ids = {j: f"P{i}" for i, j in enumerate(jids)}
    lines = ["sequenceDiagram"]
    lines += [f"    participant {ids[j]} as {mermaid_escape(names[j])}" for j in jids]
    for it in items:
        if it.get("kind") == RecordKind.MESSAGE:
            arrow = "->>" if (it.get("performative") or CHAT) in OPENING_OR_CHAT else "-->>"
            if it["seen"] != "both":
                arrow = arrow.replace(">>", ")")  # async arrow: seen by one side only
            lines.append(f"    {ids[it['sender']]}{arrow}{ids[it['receiver']]}: "
                         f"{mermaid_escape(message_label(it))}")
        else:
            over = [ids[j] for j in jids_of(it)[:2] if j in ids]
            if over:
                lines.append(f"    Note over {','.join(over)}: {mermaid_escape(note_label(it, names))}")
    return "\n".join(lines) + "\n"


def unanswered_requests(records: Iterable[dict]) -> list[dict]:
    """Opening messages (request, query-ref) with no final answer (inform, failure, refuse,
    not-understood) from their receiver later in the same conversation."""
    events = message_events(records)
    out = []
    for ev in events:
        if ev.get("performative") not in EXPECT_ANSWER:
            continue
        answered = any(
            other.get("performative") in FINAL_ANSWERS and not other.get("feedback")
            and other.get("conversation_id") == ev.get("conversation_id")
            and other["sender"] == ev["receiver"] and other.get("t", 0) >= ev.get("t", 0)
            for other in events)
        if not answered:
            out.append(ev)
    return out


def summary(records: Iterable[dict]) -> dict:
    """Counts and lists: messages, per_performative, per_agent {jid: {sent, received}},
    conversations {id: message count} (first-seen order), structure (structure records in order,
    as {t_ms, event, agent, label}), unanswered (request events without a final answer),
    one_sided (messages traced by one side only), timeouts, dropped."""
    records = list(records)
    events = message_events(records)
    t0 = min((r.get("t", 0) for r in records), default=0)
    per_agent: dict[str, dict[str, int]] = defaultdict(lambda: {"sent": 0, "received": 0})
    for ev in events:
        per_agent[ev["sender"]]["sent"] += 1
        per_agent[ev["receiver"]]["received"] += 1
    conversations = Counter(ev.get("conversation_id") or "" for ev in events)
    return {
        "messages": len(events),
        "per_performative": dict(Counter(ev.get("performative") or CHAT for ev in events)),
        "per_agent": {k: dict(v) for k, v in per_agent.items()},
        "conversations": dict(conversations),
        "structure": [{"t_ms": round((r.get("t", 0) - t0) * 1000, 3), "event": r.get("event"),
                       "agent": r.get("agent"), "label": note_label(r)}
                      for r in records if r.get("kind") == RecordKind.STRUCTURE],
        "unanswered": unanswered_requests(records),
        "one_sided": sum(ev["seen"] != "both" for ev in events),
        "timeouts": sum(r.get("kind") == RecordKind.TIMEOUT for r in records),
        "dropped": sum(r.get("kind") == RecordKind.DROPPED for r in records),
    }


def limit_items(records: list[dict], limit: int) -> tuple[list[dict], int]:
    """The records of the first `limit` timeline items (messages and notes; 0: all), and how many
    timeline items are left out."""
    items = timeline(records)
    if not limit or len(items) <= limit:
        return records, 0
    last_t = items[limit - 1].get("t", 0)
    return [r for r in records if r.get("t", 0) <= last_t], len(items) - limit


SUMMARY_EVENTS = {"spawn", "handoff", "ended", "destroy", "resume", "cloud-spawn", "cloud-destroy", "cloud-lost",
                  "estop", "strategy", "plan-failed", "heartbeat-late", "catalogue-changed"}


def idle_warm_workers(records: list[dict], agents: Iterable[str], per_agent: dict) -> set[str]:
    """The Cloud accounts among `agents` that sent and received nothing and that no cloud-spawn named:
    the Platform's warm workers, logged in ahead of time (agents/warm_pool.py) and never handed a run."""
    spawned = {bare(r.get("cloud")) for r in records
               if r.get("kind") == RecordKind.STRUCTURE and r.get("event") == "cloud-spawn" and r.get("cloud")}
    return {j for j in agents if role(j) == "cloud" and j not in spawned and not any(per_agent.get(j, {}).values())}


def summary_text(records: list[dict], title: str = "trace", events_shown: int = 40) -> str:
    """What `rapp trace show` prints by default: the agents (role, messages sent and received), the
    messages per performative, the task's structure changes in time order (repeated ones counted),
    the tasks' ends, and what went wrong (unanswered requests, timeouts, dropped messages)."""
    records = list(records)
    if not records:
        return f"{title}: no records"
    s = summary(records)
    t0 = min(r.get("t", 0) for r in records)
    span = max(r.get("t", 0) for r in records) - t0
    lines = [f"{title}: {len(records)} records over {span:.1f} s, {s['messages']} messages "
             f"({', '.join(f'{n} {p}' for p, n in sorted(s['per_performative'].items(), key=lambda kv: -kv[1]))})",
             "", "agents (--agent ROLE, NAME or JID):"]
    agents = {bare(r["agent"]) for r in records if r.get("agent")} | set(s["per_agent"])
    idle = idle_warm_workers(records, agents, s["per_agent"])
    agents = sorted(agents - idle, key=lambda j: (list(ROLES).index(role(j)) if role(j) else len(ROLES), j))
    width = max((len(local(j)) for j in agents), default=0)
    for j in agents:
        n = s["per_agent"].get(j, {"sent": 0, "received": 0})
        lines.append(f"  {role(j) or '-':8s} {local(j):{width}s}  sent {n['sent']:6d}  received {n['received']:6d}")
    if idle:
        lines.append(f"  (and {len(idle)} idle warm Cloud worker{'s' if len(idle) > 1 else ''}, logged in ahead of "
                     f"time and never handed a run: {', '.join(sorted(local(j) for j in idle))})")
    events = [r for r in records if r.get("kind") == RecordKind.STRUCTURE and r.get("event") in SUMMARY_EVENTS]
    counts = Counter(r["event"] for r in events)
    lines += ["", f"structure ({', '.join(f'{n} {e}' for e, n in counts.most_common()) or 'none'}):"]
    shown = [r for r in events if r["event"] not in ("strategy", "plan-failed")]  # counted above, often many
    for r in shown[:events_shown]:
        lines.append(f"  {r.get('t', 0) - t0:8.1f} s  {note_label(r)[:150]}")
    if len(shown) > events_shown:
        lines.append(f"  ... {len(shown) - events_shown} more (--view table)")
    ends = [r for r in records if r.get("kind") == RecordKind.STRUCTURE and r.get("event") == "ended"]
    if ends:
        lines += ["", "tasks:"]
        lines += [f"  {local(r.get('dynamic'))}: {r.get('state', '')} ({str(r.get('reason', ''))[:120]})" for r in ends]
    lines += ["", f"problems: {len(s['unanswered'])} unanswered requests, {s['timeouts']} timeouts, "
                  f"{s['dropped']} dropped messages, {s['one_sided']} messages seen by one side only",
              "", "messages: --view table|sequence|both (the first --limit N, default 200); rapp trace html FILE "
                  "for a page"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("trace")
    p.add_argument("--agent", action="append", help="keep records of this agent (repeatable)")
    p.add_argument("--conv", action="append", help="keep this conversation id/prefix (repeatable)")
    view = p.add_mutually_exclusive_group()
    view.add_argument("--mermaid", action="store_true")
    view.add_argument("--sequence", action="store_true")
    view.add_argument("--summary", action="store_true")
    a = p.parse_args(argv)
    recs = filter_records(read_trace(a.trace, validate=True), a.agent, a.conv)
    if a.mermaid:
        print(mermaid(recs), end="")
    elif a.sequence:
        print(sequence_text(recs))
    elif a.summary:
        print(json.dumps(summary(recs), indent=2, default=str))
    else:
        print(table(recs))


if __name__ == "__main__":
    main()
