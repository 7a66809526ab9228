"""Trace views: pure report functions over a known trace, and the HTML page in headless Chromium.

The browser test needs the Debian package `chromium` (/usr/bin/chromium) and the pip package
`playwright` (no `playwright install`: the system Chromium is used); it is skipped without them.
"""
from __future__ import annotations

import json
import re
import shutil
import time
from pathlib import Path

import pytest

from agents.tracing import read_trace
from scenarios.trace_html import render_html, script_json
from scenarios.trace_report import (
    filter_records,
    mermaid,
    message_events,
    sequence_text,
    summary,
    table,
    timeline,
    unanswered_requests,
)

CORE, STORE, PLATFORM = "core1@localhost", "store1@localhost", "platform1@localhost"
DYN, CLOUD, HUMAN = "dyn-hazard@localhost", "cloud1@localhost", "alice@localhost"
EVIL = '</script><img src=x onerror="window.__pwned=1"><b>bold</b>'
CONV_DL, CONV_MOVE, CONV_DETECT, CONV_LOST = ("c-d0wn10ad0000001", "c-m0ve000000000002",
                                              "c-detect000000003", "c-10st000000000004")


class TraceBuilder:
    """Records as agents.base writes them, with a clock advancing 1 ms per record by default."""

    def __init__(self, t0: float = 1_700_000_000.0):
        self.t = t0
        self.records: list[dict] = []
        self._n = 0

    def add(self, kind: str, dt: float = 0.001, **fields) -> dict:
        self.t += dt
        rec = {"t": round(self.t, 6), "kind": kind, "pid": 100, **fields}
        self.records.append(rec)
        return rec

    def message(self, sender, receiver, performative, conv, action="", content="{}", *,
                ontology="rapp", reply_to="", send=True, recv=True, path="direct",
                latency=0.0005, message_id=None) -> str:
        """Trace one message: its send and/or recv record (recv may precede send: clock skew)."""
        self._n += 1
        mid = f"m-{self._n:016x}" if message_id is None else message_id
        common = {"sender": sender, "receiver": receiver, "performative": performative,
                  "conversation_id": conv, "ontology": ontology, "action": action,
                  "message_id": mid, "in_reply_to": reply_to, "path": path,
                  "size": len(content), "content": content}
        if send:
            self.add("message", dir="send", agent=sender, **common)
        if recv:
            self.add("message", dt=latency if send else 0.001, dir="recv", agent=receiver, **common)
        return mid

    def request(self, sender, receiver, conv, action, content, answers=("agree", "inform"),
                reply="{}", path="direct"):
        mid = self.message(sender, receiver, "request", conv, action, content, path=path)
        for perf in answers:
            self.message(receiver, sender, perf, conv, action, reply if perf != "agree" else "{}",
                         reply_to=mid, path=path)


def sample_trace() -> list[dict]:
    """A run: a human asks Core by chat; Core downloads a rapp from Store, spawns a Dynamic
    agent and hands supervision to it; the Dynamic agent moves the platform, spawns a Cloud agent
    to detect hazards, loses one request (timeout), finishes, and Core resumes.
    11 messages (9 traced twice, 2 with the external human traced once), 4 conversations
    with ids + the chat, 1 unanswered request."""
    b = TraceBuilder()
    for a in (CORE, STORE, PLATFORM):
        b.add("agent", event="started", agent=a, cls="RappAgent")
    b.add("behaviour", event="activated", agent=CORE, behaviour="supervise")
    b.add("behaviour", event="activated", agent=CORE, behaviour="navigation")
    b.message(HUMAN, CORE, "chat", "", content="please check the kitchen; thanks <3",
              send=False, path="xmpp", message_id="")
    b.request(CORE, STORE, CONV_DL, "download", '{"rapp":"hazard"}',
              reply='{"package":"hazard-1.0.tar.gz","size":18231}')
    b.add("structure", event="download", agent=CORE, rapp="hazard", version="1.0")
    b.add("structure", event="spawn", agent=CORE, child=DYN, rapp="hazard")
    b.add("agent", event="started", agent=DYN, cls="DynamicAgent")
    b.add("structure", event="handoff", agent=CORE, to=DYN, behaviour="navigation")
    b.add("behaviour", event="deactivated", agent=CORE, behaviour="navigation")
    b.add("behaviour", event="activated", agent=DYN, behaviour="navigation")
    b.add("state", event="enter", agent=DYN, fsm="patrol", state="moving")
    b.request(DYN, PLATFORM, CONV_MOVE, "move_to", '{"x":1.5,"y":-2.0,"theta":0}',
              reply='{"reached":true}')
    b.add("structure", event="cloud-spawn", agent=DYN, cloud=CLOUD, image="hazard-detector")
    b.add("agent", event="started", agent=CLOUD, cls="CloudAgent")
    # cross-process: the receiver's clock is behind, its recv record comes first
    b.message(DYN, CLOUD, "request", CONV_DETECT, "detect_hazard",
              json.dumps({"image": "frame-17", "note": EVIL}), path="xmpp", latency=-0.0002)
    b.message(CLOUD, DYN, "inform", CONV_DETECT, "detect_hazard",
              json.dumps({"hazards": [{"kind": "spill", "x": 1.2, "y": -1.9}], "note": EVIL}),
              path="xmpp", latency=0.003)
    b.message(DYN, PLATFORM, "request", CONV_LOST, "move_to", '{"x":0,"y":0,"theta":0}')
    b.add("timeout", dt=5.0, agent=DYN, peer=PLATFORM, action="move_to",
          conversation_id=CONV_LOST, timeout_s=5.0)
    b.add("structure", event="cloud-destroy", agent=DYN, cloud=CLOUD)
    b.add("agent", event="stopped", agent=CLOUD, cls="CloudAgent")
    b.add("structure", event="finish", agent=DYN, rapp="hazard", ok=True)
    b.add("behaviour", event="deactivated", agent=DYN, behaviour="navigation")
    b.add("structure", event="resume", agent=CORE, behaviour="navigation", **{"from": DYN})
    b.add("behaviour", event="activated", agent=CORE, behaviour="navigation")
    b.add("structure", event="destroy", agent=CORE, child=DYN)
    b.add("agent", event="stopped", agent=DYN, cls="DynamicAgent")
    b.message(CORE, HUMAN, "chat", "", content="kitchen: 1 spill found", recv=False,
              path="xmpp", message_id="")
    return b.records


def big_trace(n_requests: int = 150) -> list[dict]:
    """Many request/inform pairs between a few agents (2 * n_requests messages)."""
    b = TraceBuilder()
    agents = [CORE, STORE, PLATFORM, DYN]
    for i in range(n_requests):
        a, c = agents[i % 4], agents[(i + 1) % 4]
        b.request(a, c, f"c-{i:016x}", "ping", json.dumps({"i": i}), answers=("inform",))
    return b.records


@pytest.fixture
def records(tmp_path) -> list[dict]:
    """The sample trace, written as JSON Lines in shuffled order and read back with read_trace."""
    recs = sample_trace()
    path = tmp_path / "trace.jsonl"
    lines = [json.dumps(r) for r in recs]
    path.write_text("\n".join(lines[::2] + lines[1::2]) + "\nnot json\n", encoding="utf-8")
    back = read_trace(path)
    assert len(back) == len(recs)
    return back


# -- pure functions --------------------------------------------------------------------------
def test_message_events_dedupe_send_recv_pairs(records):
    events = message_events(records)
    assert len([r for r in records if r["kind"] == "message"]) == 20
    assert len(events) == 11
    assert [e["performative"] for e in events] == [
        "chat", "request", "agree", "inform", "request", "agree", "inform",
        "request", "inform", "request", "chat"]
    both = [e for e in events if e["seen"] == "both"]
    assert len(both) == 9 and all(e["latency"] is not None for e in both)
    assert {(e["sender"], e["seen"]) for e in events if e["seen"] != "both"} == {
        (HUMAN, "recv"), (CORE, "send")}
    detect = next(e for e in events if e["action"] == "detect_hazard")
    assert detect["t"] == detect["send_t"] and detect["latency"] == pytest.approx(-0.0002)
    assert detect["path"] == "xmpp"
    assert all("dir" not in e and "pid" not in e for e in events)


def test_dedupe_of_plain_chat_without_message_id():
    b = TraceBuilder()
    for text in ("hi", "hi", "bye"):
        b.message(CORE, STORE, "chat", "", content=text, message_id="")
    events = message_events(b.records)
    assert [e["content"] for e in events] == ["hi", "hi", "bye"]
    assert all(e["seen"] == "both" for e in events)


def test_filter_by_agent_matches_local_part_bare_and_full_jid(records):
    by_local = filter_records(records, agents=["platform1"])
    assert by_local == filter_records(records, agents=[PLATFORM])
    assert by_local == filter_records(records, agents=[PLATFORM + "/robot"])
    assert len(message_events(by_local)) == 4  # move_to request/agree/inform + lost request
    assert {r["kind"] for r in by_local} == {"agent", "message", "timeout"}  # timeout's peer
    assert filter_records(records, agents=["core"]) == []  # no partial local-part matches
    cloud = filter_records(records, agents=["cloud1"])
    assert len(message_events(cloud)) == 2
    assert {r.get("event") for r in cloud if r["kind"] == "structure"} == {"cloud-spawn", "cloud-destroy"}
    assert len(message_events(filter_records(records, agents=["alice", "cloud1"]))) == 4


def test_filter_by_conversation_by_id_or_short_prefix(records):
    full = filter_records(records, conversations=[CONV_MOVE])
    assert len(message_events(full)) == 3
    assert full == filter_records(records, conversations=["m0ve0000"])
    assert full == filter_records(records, conversations=["c-m0ve"])
    both = filter_records(records, agents=["dyn-hazard"], conversations=[CONV_LOST])
    assert [r["kind"] for r in both] == ["message", "message", "timeout"]
    assert filter_records(records) == records


def test_unanswered_requests_and_summary(records):
    lost = unanswered_requests(records)
    assert [(e["conversation_id"], e["action"]) for e in lost] == [(CONV_LOST, "move_to")]
    s = summary(records)
    assert s["messages"] == 11
    assert s["per_performative"] == {"chat": 2, "request": 4, "agree": 2, "inform": 3}
    assert s["per_agent"][DYN] == {"sent": 3, "received": 3}
    assert s["per_agent"][HUMAN] == {"sent": 1, "received": 1}
    assert list(s["conversations"]) == ["", CONV_DL, CONV_MOVE, CONV_DETECT, CONV_LOST]
    assert [x["event"] for x in s["structure"]] == [
        "download", "spawn", "handoff", "cloud-spawn", "cloud-destroy", "finish", "resume", "destroy"]
    assert s["unanswered"] == lost and s["one_sided"] == 2 and s["timeouts"] == 1
    json.dumps(s)  # serialisable


def test_unanswered_ignores_agree_and_counts_refuse_as_final():
    b = TraceBuilder()
    b.request(CORE, STORE, "c-a", "download", "{}", answers=("agree",))
    b.request(CORE, STORE, "c-b", "download", "{}", answers=("refuse",))
    b.request(CORE, STORE, "c-c", "download", "{}", answers=("not-understood",))
    assert [e["conversation_id"] for e in unanswered_requests(b.records)] == ["c-a"]


def test_table_lines(records):
    text = table(records)
    lines = text.splitlines()
    assert len(lines) == 2 + len(timeline(records))
    assert re.search(r"core1\s+→ store1\s+request\s+download\s+d0wn10ad\s+direct\s+17", text)
    assert re.search(r"alice\s+→ core1\s+chat .*xmpp\(recv\)", text)
    assert re.search(r"dyn-hazard\s+→ cloud1\s+request\s+detect_hazard\s+detect00\s+xmpp", text)
    assert "== spawn dyn-hazard@localhost by core1 rapp=hazard ==" in text
    assert "== handoff dyn-hazard@localhost by core1 behaviour=navigation ==" in text
    assert "== navigation activated on dyn-hazard ==" in text
    assert "== timeout dyn-hazard waiting move_to from platform1 ==" in text
    assert lines[2].split()[:2] == ["0.0", "=="]  # relative ms from the first record
    assert lines[7].split()[0] == "5.0"


def test_sequence_text_columns_and_arrows(records):
    text = sequence_text(records)
    lines = text.splitlines()
    header = lines[0]
    for name in ("alice", "core1", "store1", "dyn-hazard", "platform1", "cloud1"):
        assert name in header
    arrows = [ln for ln in lines if "->|" in ln or "|<-" in ln or ">|" in ln or "|<" in ln]
    assert len(arrows) == 11
    assert any("request download" in ln for ln in lines)
    assert any(ln.strip().endswith("== spawn dyn-hazard@localhost by core1 rapp=hazard ==")
               for ln in lines)
    # the store's answer points left, from store1 back to core1
    idx = next(i for i, ln in enumerate(lines) if "agree download" in ln)
    assert "<-" in lines[idx + 1]


def test_mermaid_syntax_basics(records):
    text = mermaid(records)
    lines = text.splitlines()
    assert lines[0] == "sequenceDiagram"
    parts = dict(re.findall(r"^    participant (P\d+) as (\S+)$", text, re.MULTILINE))
    assert set(parts.values()) == {"alice", "core1", "store1", "dyn-hazard", "platform1", "cloud1"}
    p = {v: k for k, v in parts.items()}
    assert f"    {p['core1']}->>{p['store1']}: request download" in lines
    assert f"    {p['store1']}-->>{p['core1']}: inform download" in lines
    assert f"    {p['alice']}-){p['core1']}: chat" in lines  # traced by one side only
    assert any(ln.startswith(f"    Note over {p['core1']},{p['dyn-hazard']}: spawn") for ln in lines)
    body = lines[1:]
    for ln in body:
        assert re.match(r"^    (participant P\d+ as |P\d+(->>|-->>|-\)|--\))P\d+: |Note over P\d+(,P\d+)?: )", ln), ln
        assert ";" not in ln.replace("#59;", "").replace("#35;", "").replace("#lt;", "") \
            .replace("#gt;", "").replace("#quot;", "").replace("#37;", "").replace("#123;", "") \
            .replace("#125;", "")
    b = TraceBuilder()
    b.add("structure", event="note", agent=CORE, text='a;b #c <d> "e" %%f\nnext')
    note = mermaid(b.records).splitlines()[-1]
    assert "\n" not in note and "<" not in note and '"' not in note and "%%" not in note
    assert "a#59;b #35;c #lt;d#gt; #quot;e#quot; #37;#37;f next" in note


def test_html_is_self_contained_and_escaped(records):
    page = render_html(records, title="run <1>")
    assert page.count("</script>") == 2  # the data script and the code script, nothing injected
    assert "<img" not in page and "<b>bold" not in page
    assert "<title>run &lt;1&gt;</title>" in page
    assert not re.search(r"(src|href)=\"?(https?:)?//", page)  # no CDN or remote resource
    data = json.loads(re.search(r'<script type="application/json" id="trace-data">(.*?)</script>',
                                page, re.DOTALL).group(1))
    assert len([i for i in data["items"] if i["kind"] == "message"]) == 11
    detect = [i for i in data["items"] if i.get("action") == "detect_hazard"]
    assert all(json.loads(i["content"])["note"] == EVIL for i in detect)  # intact once parsed
    assert json.loads(script_json({"x": "</script>\u2028"})) == {"x": "</script>\u2028"}


# -- the page in a real headless browser -------------------------------------------------------
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


@pytest.fixture
def browser_page():
    sync_api = pytest.importorskip("playwright.sync_api",
                                   reason="pip package 'playwright' is not installed")
    exe = CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium")
    if not exe:
        pytest.skip("Debian package 'chromium' is not installed (no /usr/bin/chromium)")
    with sync_api.sync_playwright() as pw:
        try:
            browser = pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS, timeout=15000)
        except Exception as e:  # noqa: BLE001 - a broken browser install is an environment issue
            pytest.skip(f"chromium at {exe} does not start under playwright: {e}")
        page = browser.new_page(viewport={"width": 1500, "height": 900})
        page.set_default_timeout(5000)
        page.problems = []
        page.on("console", lambda m: m.type == "error" and page.problems.append(m.text))
        page.on("pageerror", lambda e: page.problems.append(str(e)))
        page.route("**/*", lambda route: route.abort() if not route.request.url.startswith("file:")
                   else route.continue_())  # offline: anything remote would fail loudly
        try:
            yield page
        finally:
            browser.close()


def _open(page, tmp_path, records, name="trace.html") -> None:
    path = tmp_path / name
    path.write_text(render_html(records, title="Hazard run"), encoding="utf-8")
    page.goto(path.as_uri())
    page.wait_for_selector("#diagram g.msg")


def _count(page) -> int:
    shown = page.locator("#diagram g.msg").count()
    assert int(page.get_attribute("#msg-count", "data-count")) == shown
    return shown


def test_html_page_in_headless_chromium(browser_page, records, tmp_path):
    page = browser_page
    started = time.monotonic()
    _open(page, tmp_path, records)
    assert _count(page) == 11
    assert page.locator("#diagram-header .head").count() == 6
    assert page.locator("#diagram g.structure").count() == len(
        [r for r in records if r["kind"] != "message"])
    assert page.locator("#diagram g.structure[data-event='spawn']").count() == 1
    assert page.locator("#diagram g.msg[data-performative='request']").count() == 4
    page.screenshot(path=str(tmp_path / "trace.png"))

    # agent filter: only Dynamic and Platform -> messages between them
    page.click("#agents-none")
    assert _count(page) == 0
    page.check(f"#agent-filter input[value='{DYN}']")
    page.check(f"#agent-filter input[value='{PLATFORM}']")
    assert _count(page) == 4
    assert page.locator("#diagram-header .head").count() == 2
    page.select_option("#agent-mode", "either")  # anything involving them
    assert _count(page) == 6
    page.click("#agents-all")
    page.uncheck(f"#agent-filter input[value='{HUMAN}']")
    page.select_option("#agent-mode", "both")
    assert _count(page) == 9

    # conversation filter
    page.click("#agents-all")
    page.select_option("#conv-filter", CONV_MOVE)
    assert _count(page) == 3
    assert page.locator(f"#diagram g.msg[data-conv='{CONV_MOVE}']").count() == 3
    page.select_option("#conv-filter", CONV_DETECT)
    assert _count(page) == 2

    # clicking an arrow shows its record, content pretty-printed, injected markup kept as text
    page.locator("#diagram g.msg[data-performative='inform']").first.click()
    details = page.locator("#details")
    assert "inform detect_hazard" in details.inner_text()
    content = page.locator("#details-content").inner_text()
    assert '"hazards": [' in content and '"kind": "spill"' in content
    assert json.loads(content)["note"] == EVIL  # shown as text, not markup
    assert page.locator("#details img, #diagram img").count() == 0
    assert page.evaluate("window.__pwned") is None
    page.select_option("#conv-filter", "")
    assert _count(page) == 11

    assert page.problems == []
    assert time.monotonic() - started < 20


def test_html_page_with_hundreds_of_messages(browser_page, tmp_path):
    page = browser_page
    _open(page, tmp_path, big_trace(200), name="big.html")
    assert _count(page) == 400
    scroll = page.locator("#diagram-scroll")
    assert scroll.evaluate("e => e.scrollHeight > e.clientHeight")  # scrolls, page does not grow
    page.select_option("#conv-filter", f"c-{7:016x}")
    assert _count(page) == 2
    assert page.problems == []
