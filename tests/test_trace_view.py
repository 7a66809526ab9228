"""Trace views over a golden trace recorded from a real run (tests/data/golden_trace.jsonl, see
tests/data/README.md): pure report functions, and the HTML page in headless Chromium.

The run: a robot owner says "goldendemo" to the Core of a simulated NAO; the Core downloads the
RApp from the Store (download_info, download_chunk), spawns its Dynamic Agent and hands supervision
to it; the Dynamic Agent asks the Core for robot actions (say, get_global_pose, capture_image),
pings the Platform, has the Platform start its Cloud Agent (cloud-spawn), asks it to double 21,
reports, stops its Cloud Agent (cloud-destroy) and finishes; the Core destroys it and resumes.

The browser test needs the Debian package `chromium` (/usr/bin/chromium) and the pip package
`playwright` (no `playwright install`: the system Chromium is used); it is skipped without them.
"""
from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest

from agents.tracing import read_trace
from scenarios.trace_html import note_category, render_html, script_json
from scenarios.trace_report import (
    filter_records,
    mermaid,
    message_events,
    sequence_text,
    summary,
    summary_text,
    table,
    timeline,
    unanswered_requests,
)

GOLDEN = Path(__file__).resolve().parent / "data" / "golden_trace.jsonl"
CORE, STORE, PLATFORM = "core-nao1@localhost", "store@localhost", "platform@localhost"
OWNER, PUBLISHER = "owner-nao1@localhost", "publisher@localhost"
DYN = "dyn-nao1-golden-demo-30cf2e5a44@localhost"
CLOUD = "cloud-golden-demo-4630413466@localhost"
NAMES = {"publisher", "store", "core-nao1", "platform", "owner-nao1", "dyn-nao1-golden-demo-30cf2e5a44",
         "cloud-golden-demo-4630413466"}
N_RECORDS, N_MESSAGE_RECORDS, N_MESSAGES = 202, 132, 68
EVIL = '</script><img src=x onerror="window.__pwned=1"><b>bold</b>'


def conv_of(records: list[dict], action: str, sender: str | None = None) -> str:
    """The conversation id of the first request of `action` (from `sender`)."""
    return next(r["conversation_id"] for r in records if r["kind"] == "message" and r["action"] == action
                and r["performative"] in ("request", "subscribe") and sender in (None, r["sender"]))


@pytest.fixture(scope="module")
def golden() -> list[dict]:
    return read_trace(GOLDEN, validate=True)


@pytest.fixture
def records(tmp_path, golden) -> list[dict]:
    """The golden trace, written in shuffled order with a broken line and a record that is not an
    ontology.trace record, and read back with read_trace: both are skipped, the order restored."""
    path = tmp_path / "trace.jsonl"
    lines = [json.dumps(r) for r in golden]
    stray = json.dumps({"t": golden[5]["t"], "kind": "structure", "event": "finish", "pid": 1, "agent": DYN})
    path.write_text("\n".join(lines[::2] + lines[1::2]) + "\nnot json\n" + stray + "\n", encoding="utf-8")
    back = read_trace(path, validate=True)
    assert back == golden and len(back) == N_RECORDS
    assert len(read_trace(path)) == N_RECORDS + 1  # without validation only the broken line goes
    return back


def with_lost_answer(records: list[dict]) -> tuple[list[dict], str]:
    """The run as if the Core's answer to the Dynamic Agent's get_global_pose had been lost: the
    inform records dropped and the Dynamic Agent's timeout recorded 30 s later."""
    conv = conv_of(records, "get_global_pose", DYN)
    request = next(r for r in records if r.get("conversation_id") == conv and r["kind"] == "message")
    out = [r for r in records if not (r.get("conversation_id") == conv and r.get("performative") == "inform")]
    out.append({"t": request["t"] + 30.0, "kind": "timeout", "pid": request["pid"], "agent": DYN,
                "peer": CORE, "action": "get_global_pose", "conversation_id": conv, "timeout_s": 30.0})
    return sorted(out, key=lambda r: r["t"]), conv


def with_hostile_answer(records: list[dict]) -> list[dict]:
    """The run as if the Cloud Agent (a RApp author's code) had put markup in its answer."""
    conv = conv_of(records, "double", DYN)
    evil = json.dumps({"value": 42, "note": EVIL})
    return [dict(r, content=evil, size=len(evil))
            if r.get("conversation_id") == conv and r.get("performative") == "inform" else r for r in records]


def with_clock_skew(records: list[dict], conv: str, skew: float) -> list[dict]:
    """The receiver's records of `conv` written by a clock `skew` seconds behind (another process)."""
    return [dict(r, t=r["t"] - skew) if r.get("conversation_id") == conv and r.get("dir") == "recv" else r
            for r in records]


class TraceBuilder:
    """Tiny hand-made traces for edge cases a real run does not show (records as agents.base
    writes them, with a clock advancing 1 ms per record)."""

    def __init__(self, t0: float = 1_700_000_000.0):
        self.t = t0
        self.records: list[dict] = []
        self._n = 0

    def add(self, kind: str, dt: float = 0.001, **fields) -> dict:
        self.t += dt
        rec = {"t": round(self.t, 6), "kind": kind, "pid": 100, **fields}
        self.records.append(rec)
        return rec

    def message(self, sender, receiver, performative, conv, action="", content="{}", *, reply_to="",
                message_id=None) -> str:
        self._n += 1
        mid = f"m-{self._n:016x}" if message_id is None else message_id
        common = {"sender": sender, "receiver": receiver, "performative": performative,
                  "conversation_id": conv, "ontology": "store", "action": action, "message_id": mid,
                  "in_reply_to": reply_to, "path": "direct", "size": len(content), "content": content}
        self.add("message", dir="send", agent=sender, **common)
        self.add("message", dt=0.0005, dir="recv", agent=receiver, **common)
        return mid

    def request(self, sender, receiver, conv, action, answers):
        mid = self.message(sender, receiver, "request", conv, action)
        for perf in answers:
            self.message(receiver, sender, perf, conv, action, reply_to=mid)


# -- pure functions --------------------------------------------------------------------------
def test_golden_trace_holds_the_real_vocabulary(golden):
    assert GOLDEN.stat().st_size < 300_000
    events = message_events(golden)
    to_store = {e["action"] for e in events if e["sender"] == CORE and e["receiver"] == STORE}
    assert {"download_info", "download_chunk"} <= to_store  # the Core downloads the RApp
    robot = [e["action"] for e in events if e["sender"] == DYN and e["receiver"] == CORE
             and e["performative"] == "request"]
    assert robot == ["task_status", "task_status", "say", "get_global_pose", "capture_image", "report",
                     "task_status"]
    assert [e["action"] for e in events if CLOUD in (e["sender"], e["receiver"])] == [
        "cloud_ready", "cloud_ready", "double", "double"]
    structure = [(r["event"], r["agent"]) for r in golden if r["kind"] == "structure"]
    for step in [("download", CORE), ("spawn", CORE), ("handoff", CORE), ("cloud-spawn", PLATFORM),
                 ("cloud-destroy", PLATFORM), ("ended", CORE), ("destroy", CORE), ("resume", CORE)]:
        assert step in structure, step
    order = [e for e, _ in structure]
    assert order.index("spawn") < order.index("handoff") < order.index("cloud-spawn") \
        < order.index("cloud-destroy") < order.index("destroy") < order.index("resume")


def test_message_events_dedupe_send_recv_pairs(records):
    events = message_events(records)
    assert len([r for r in records if r["kind"] == "message"]) == N_MESSAGE_RECORDS
    assert len(events) == N_MESSAGES
    assert [(e["performative"], e["action"]) for e in events[:4]] == [
        ("request", "register_owner"), ("inform", "register_owner"), ("request", "upload_chunk"),
        ("inform", "upload_chunk")]
    both = [e for e in events if e["seen"] == "both"]
    assert len(both) == N_MESSAGES - 4 and all(e["latency"] is not None for e in both)
    # the owner is an external XMPP client: its chat is traced by the Core's side only
    assert {(e["sender"], e["seen"]) for e in events if e["seen"] != "both"} == {(OWNER, "recv"), (CORE, "send")}
    chunk = next(e for e in events if e["action"] == "download_chunk" and e["sender"] == CORE)
    assert chunk["path"] == "direct" and chunk["latency"] >= 0 and chunk["t"] == chunk["send_t"]
    assert all("dir" not in e and "pid" not in e for e in events)


def test_clock_skew_between_processes(golden):
    # cross-process: the receiver's clock is behind, its recv record comes first
    conv = conv_of(golden, "double", DYN)
    request = next(e for e in message_events(golden) if e["conversation_id"] == conv)
    skew = request["latency"] + 0.0002
    events = [e for e in message_events(with_clock_skew(golden, conv, skew)) if e["conversation_id"] == conv]
    assert [e["performative"] for e in events] == ["request", "inform"]
    double = events[0]
    assert double["t"] == double["send_t"] and double["latency"] == pytest.approx(-0.0002, abs=1e-6)
    assert double["path"] == "xmpp" and double["seen"] == "both"


def test_dedupe_of_plain_chat_without_message_id():
    b = TraceBuilder()
    for text in ("hi", "hi", "bye"):
        b.message(CORE, STORE, "chat", "", content=text, message_id="")
    events = message_events(b.records)
    assert [e["content"] for e in events] == ["hi", "hi", "bye"]
    assert all(e["seen"] == "both" for e in events)


def test_filter_by_agent_matches_local_part_bare_and_full_jid(records):
    by_local = filter_records(records, agents=["platform"])
    assert by_local == filter_records(records, agents=[PLATFORM])
    assert by_local == filter_records(records, agents=[PLATFORM + "/robot"])
    assert len(message_events(by_local)) == 24
    assert {r["kind"] for r in by_local} == {"agent", "behaviour", "message", "structure"}
    assert filter_records(records, agents=["core-n"]) == []  # no partial local-part matches
    cloud = filter_records(records, agents=[CLOUD.split("@")[0]])
    assert len(message_events(cloud)) == 4
    # a role: every agent of that kind, whatever its (random) name (--agent dyn, cloud, core, ...)
    assert filter_records(records, agents=["cloud"]) == cloud
    assert filter_records(records, agents=["core"]) == filter_records(records, agents=["core-nao1"])
    assert {r.get("event") for r in cloud if r["kind"] == "structure"} == {
        "cloud-spawn", "cloud-destroy", "account-deleted"}
    assert len(message_events(filter_records(records, agents=["owner-nao1", CLOUD]))) == 8


def test_filter_by_conversation_by_id_or_short_prefix(records):
    conv = conv_of(records, "get_global_pose", DYN)
    full = filter_records(records, conversations=[conv])
    assert len(message_events(full)) == 2
    assert full == filter_records(records, conversations=[conv[2:10]])
    assert full == filter_records(records, conversations=[conv[:6]])
    # the heartbeat the Core got before its supervision of the Dynamic Agent began: dropped
    dropped = next(r for r in records if r["kind"] == "dropped")
    both = filter_records(records, agents=["dyn-nao1-golden-demo-30cf2e5a44"],
                          conversations=[dropped["conversation_id"]])
    assert [r["kind"] for r in both] == ["message", "message", "dropped"]
    assert filter_records(records) == records


def test_the_summary_leaves_idle_warm_cloud_workers_out_of_the_agents(golden):
    """The Platform logs a warm Cloud worker in ahead of time; one never handed a run sent and received
    nothing: named once below the agents, not listed as an agent. A Cloud Agent a cloud-spawn named
    stays listed, even silent."""
    t = golden[-1]["t"]
    idle, silent = "cloud-9733a7ae98@localhost", "cloud-golden-demo-0000000000@localhost"
    extra = [{"t": t, "kind": "agent", "pid": 1, "event": "started", "agent": idle, "cls": "CloudAgent", "origin": idle},
             {"t": t, "kind": "structure", "pid": 2, "event": "cloud-spawn", "agent": PLATFORM, "cloud": silent,
              "rapp": "golden-demo", "owner": DYN, "sandbox": True, "warm": True},
             {"t": t, "kind": "agent", "pid": 3, "event": "started", "agent": silent, "cls": "CloudAgent", "origin": silent}]
    text = summary_text(golden + extra, "golden")
    agents = text.split("agents (")[1].split("\n\n")[0].splitlines()[1:]
    assert not any("cloud-9733a7ae98" in line for line in agents[:-1]), text
    assert "1 idle warm Cloud worker" in agents[-1] and "cloud-9733a7ae98" in agents[-1], text
    listed = {line.split()[1] for line in agents[:-1]}
    assert {"cloud-golden-demo-0000000000", "cloud-golden-demo-4630413466"} <= listed, text
    assert "idle warm" not in summary_text(golden, "golden")


def test_unanswered_requests_and_summary(records):
    assert unanswered_requests(records) == []  # the real run answered every request
    s = summary(records)
    assert s["messages"] == N_MESSAGES
    assert s["per_performative"] == {"request": 28, "inform": 35, "subscribe": 1, "chat": 4}
    assert s["per_agent"][DYN] == {"sent": 17, "received": 11}
    assert s["per_agent"][OWNER] == {"sent": 1, "received": 3}
    assert s["per_agent"][CLOUD] == {"sent": 2, "received": 2}
    assert list(s["conversations"])[:2] == [conv_of(records, "register_owner", PUBLISHER),
                                            conv_of(records, "upload_chunk", PUBLISHER)]
    assert s["conversations"][""] == 4  # the chat
    assert [x["event"] for x in s["structure"]] == [
        "publish", "init", "register", "register", "register", "vocabulary", "command", "download",
        "download", "spawn", "status", "handoff", "status", "download", "cloud-spawn", "cloud-destroy",
        "account-deleted", "status", "ended", "destroy", "resume", "account-deleted"]
    assert s["one_sided"] == 4 and s["timeouts"] == 0 and s["dropped"] == 1
    json.dumps(s)  # serialisable

    lost, conv = with_lost_answer(records)
    assert [(e["conversation_id"], e["action"]) for e in unanswered_requests(lost)] == [(conv, "get_global_pose")]
    s = summary(lost)
    assert s["unanswered"] == unanswered_requests(lost) and s["timeouts"] == 1
    assert s["messages"] == N_MESSAGES - 1


def test_unanswered_ignores_agree_and_counts_refuse_as_final():
    b = TraceBuilder()
    b.request(CORE, STORE, "c-a", "download_info", answers=("agree",))
    b.request(CORE, STORE, "c-b", "download_info", answers=("refuse",))
    b.request(CORE, STORE, "c-c", "download_info", answers=("not-understood",))
    assert [e["conversation_id"] for e in unanswered_requests(b.records)] == ["c-a"]


def test_table_lines(records):
    text = table(records)
    lines = text.splitlines()
    assert len(lines) == 2 + len(timeline(records))
    short = conv_of(records, "download_chunk", CORE)[2:10]
    assert re.search(rf"core-nao1\s+→ store\s+request\s+download_chunk\s+{short}\s+direct\s+93", text)
    assert re.search(r"owner-nao1\s+→ core-nao1\s+chat .*xmpp\(recv\)", text)
    assert re.search(r"dyn-nao1-golden-demo-30cf2e5a44 → cloud-golden-demo-4630413466\s+request\s+double\s+"
                     r"3c97a776\s+xmpp", text)
    assert ("== spawn dyn-nao1-golden-demo-30cf2e5a44@localhost by core-nao1 rapp=golden-demo version=0.1.0 "
            "sandbox=true ==") in text
    assert "== handoff dyn-nao1-golden-demo-30cf2e5a44@localhost by core-nao1 rapp=golden-demo ==" in text
    assert "== task activated on dyn-nao1-golden-demo-30cf2e5a44 ==" in text
    assert "== resume by core-nao1 robot=nao1 ==" in text
    assert lines[2].split()[:2] == ["0.0", "=="]  # relative ms from the first record
    assert lines[8].split()[:4] == ["6.1", "publisher", "→", "store"]
    lost, _ = with_lost_answer(records)
    assert "== timeout dyn-nao1-golden-demo-30cf2e5a44 waiting get_global_pose from core-nao1 ==" in table(lost)


def test_sequence_text_columns_and_arrows(records):
    text = sequence_text(records)
    lines = text.splitlines()
    header = lines[0]
    for name in NAMES:
        assert name in header
    arrows = [ln for ln in lines if "->|" in ln or "|<-" in ln or ">|" in ln or "|<" in ln]
    assert len(arrows) == N_MESSAGES
    assert any("request download_chunk" in ln for ln in lines)
    assert any(ln.strip().endswith("== spawn dyn-nao1-golden-demo-30cf2e5a44@localhost by core-nao1 "
                                   "rapp=golden-demo version=0.1.0 sandbox=true ==") for ln in lines)
    # the Dynamic Agent's column is right of the Core's: its request points left, the answer right
    idx = next(i for i, ln in enumerate(lines) if "request say" in ln)
    assert "|<-" in lines[idx + 1]
    idx = next(i for i, ln in enumerate(lines) if "inform say" in ln)
    assert "->|" in lines[idx + 1]


def test_mermaid_syntax_basics(records):
    text = mermaid(records)
    lines = text.splitlines()
    assert lines[0] == "sequenceDiagram"
    parts = dict(re.findall(r"^    participant (P\d+) as (\S+)$", text, re.MULTILINE))
    assert set(parts.values()) == NAMES
    p = {v: k for k, v in parts.items()}
    dyn = "dyn-nao1-golden-demo-30cf2e5a44"
    assert f"    {p['core-nao1']}->>{p['store']}: request download_chunk" in lines
    assert f"    {p['store']}-->>{p['core-nao1']}: inform download_chunk" in lines
    assert f"    {p[dyn]}->>{p['core-nao1']}: request capture_image" in lines
    assert f"    {p['core-nao1']}->>{p['store']}: subscribe subscribe_catalogue" in lines  # opens, like a request
    assert f"    {p['owner-nao1']}-){p['core-nao1']}: chat" in lines  # traced by one side only
    assert any(ln.startswith(f"    Note over {p['core-nao1']},{p[dyn]}: spawn") for ln in lines)
    body = lines[1:]
    for ln in body:
        assert re.match(r"^    (participant P\d+ as |P\d+(->>|-->>|-\)|--\))P\d+: |Note over P\d+(,P\d+)?: )", ln), ln
        assert ";" not in ln.replace("#59;", "").replace("#35;", "").replace("#lt;", "") \
            .replace("#gt;", "").replace("#quot;", "").replace("#37;", "").replace("#123;", "") \
            .replace("#125;", "")
    b = TraceBuilder()
    b.add("structure", event="command", agent=CORE, text='a;b #c <d> "e" %%f\nnext')
    note = mermaid(b.records).splitlines()[-1]
    assert "\n" not in note and "<" not in note and '"' not in note and "%%" not in note
    assert "a#59;b #35;c #lt;d#gt; #quot;e#quot; #37;#37;f next" in note


def test_note_categories_of_the_real_events(records):
    cats = {(r["kind"], r.get("event")): note_category(r) for r in records if r["kind"] != "message"}
    assert cats[("structure", "spawn")] == cats[("structure", "cloud-spawn")] == "created"
    assert cats[("structure", "download")] == cats[("agent", "started")] == "created"
    assert cats[("structure", "destroy")] == cats[("structure", "cloud-destroy")] == "destroyed"
    assert cats[("agent", "stopped")] == "destroyed"
    assert cats[("structure", "handoff")] == "handoff" and cats[("structure", "resume")] == "handback"
    assert cats[("behaviour", "activated")] == "activated" and cats[("state", "enter")] == "state"
    assert cats[("dropped", None)] == "problem" and cats[("structure", "status")] == "structure"


def test_html_is_self_contained_and_escaped(records):
    page = render_html(with_hostile_answer(records), title="run <1>")
    assert page.count("</script>") == 2  # the data script and the code script, nothing injected
    assert "<img src=x" not in page and "<b>bold" not in page  # (the page's own
    # <img> elements are the scene's map and camera frame, filled by its script)
    assert "<title>run &lt;1&gt;</title>" in page
    assert not re.search(r"(src|href)=\"?(https?:)?//", page)  # no CDN or remote resource
    assert 'const OPENING = ["request", "query-ref", "subscribe", "chat"];' in page
    data = json.loads(re.search(r'<script type="application/json" id="trace-data">(.*?)</script>',
                                page, re.DOTALL).group(1))
    assert len([i for i in data["items"] if i["kind"] == "message"]) == N_MESSAGES
    double = [i for i in data["items"] if i.get("action") == "double" and i["performative"] == "inform"]
    assert len(double) == 1 and json.loads(double[0]["content"])["note"] == EVIL  # intact once parsed
    assert json.loads(script_json({"x": "</script>\u2028"})) == {"x": "</script>\u2028"}


# -- the page in a real headless browser -------------------------------------------------------
def _open(page, tmp_path, records, name="trace.html") -> None:
    path = tmp_path / name
    path.write_text(render_html(records, title="Golden run"), encoding="utf-8")
    page.goto(path.as_uri())
    page.wait_for_selector("#diagram g.msg")


def _count(page) -> int:
    shown = page.locator("#diagram g.msg").count()
    assert int(page.get_attribute("#msg-count", "data-count")) == shown
    return shown


def test_html_page_in_headless_chromium(browser_page, records, tmp_path):
    page = browser_page
    started = time.monotonic()
    _open(page, tmp_path, with_hostile_answer(records))
    assert _count(page) == N_MESSAGES
    assert page.locator("#diagram-header .head").count() == len(NAMES)
    assert page.locator("#diagram g.structure").count() == len(
        [r for r in records if r["kind"] != "message"])
    assert page.locator("#diagram g.structure[data-event='spawn']").count() == 1
    assert page.locator("#diagram g.structure[data-event='cloud-spawn']").count() == 1
    assert page.locator("#diagram g.msg[data-performative='request']").count() == 28
    page.screenshot(path=str(tmp_path / "trace.png"))

    # agent filter: only the Dynamic Agent and its Cloud Agent -> messages between them
    page.click("#agents-none")
    assert _count(page) == 0
    page.check(f"#agent-filter input[value='{DYN}']")
    page.check(f"#agent-filter input[value='{CLOUD}']")
    assert _count(page) == 2
    assert page.locator("#diagram-header .head").count() == 2
    page.select_option("#agent-mode", "either")  # anything involving them
    assert _count(page) == 30
    page.click("#agents-all")
    page.uncheck(f"#agent-filter input[value='{OWNER}']")
    page.select_option("#agent-mode", "both")
    assert _count(page) == N_MESSAGES - 4

    # conversation filter
    page.click("#agents-all")
    pose = conv_of(records, "get_global_pose", DYN)
    page.select_option("#conv-filter", pose)
    assert _count(page) == 2
    assert page.locator(f"#diagram g.msg[data-conv='{pose}']").count() == 2
    page.select_option("#conv-filter", conv_of(records, "double", DYN))
    assert _count(page) == 2

    # clicking an arrow shows its record, content pretty-printed, injected markup kept as text
    page.locator("#diagram g.msg[data-performative='inform']").first.click()
    details = page.locator("#details")
    assert "inform double" in details.inner_text()
    content = page.locator("#details-content").inner_text()
    assert '"value": 42' in content
    assert json.loads(content)["note"] == EVIL  # shown as text, not markup
    assert page.locator("#details img, #diagram img").count() == 0
    assert page.evaluate("window.__pwned") is None
    page.select_option("#conv-filter", "")
    assert _count(page) == N_MESSAGES

    assert page.problems == []
    assert time.monotonic() - started < 20


def big_trace(records: list[dict], copies: int) -> list[dict]:
    """The golden run's messages `copies` times over, one after another, each copy with its own
    conversation ids."""
    msgs = [r for r in records if r["kind"] == "message"]
    span = msgs[-1]["t"] - msgs[0]["t"] + 1.0
    return [dict(r, t=r["t"] + k * span, conversation_id=f"{r['conversation_id']}-{k}")
            for k in range(copies) for r in msgs]


def test_html_page_with_hundreds_of_messages(browser_page, golden, tmp_path):
    page = browser_page
    _open(page, tmp_path, big_trace(golden, 6), name="big.html")
    assert _count(page) == 6 * N_MESSAGES
    scroll = page.locator("#diagram-scroll")
    assert scroll.evaluate("e => e.scrollHeight > e.clientHeight")  # scrolls, page does not grow
    page.select_option("#conv-filter", conv_of(golden, "download_chunk", CORE) + "-3")
    assert _count(page) == 2
    assert page.problems == []
