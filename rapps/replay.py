"""`rapp replay RUN_DIR`: a recorded run's RApp run again as a Dynamic Agent against the recorded
answers of its Core, Platform and Cloud Agent (docs/recordings.md). No simulation, no Store: an
embedded XMPP server of its own, the RApp's Dynamic Agent (its package from the recording, or a
changed one: `rapp_dir`) and one agent standing for each peer it talked to, named as in the recording
and answering from it. The result is the first divergence (a request the recording does not have
next, one with other content, or one the recording has and the RApp did not send) or none.

How the recording is followed (the Dynamic Agent's own view, in its order):
- each request the RApp sends is matched to the first request of the recording not yet matched to
  the same peer with the same performative, ontology and action, and no earlier request of the
  recording may be left behind unless it was still waiting for its answer when this one was sent
  (requests in flight together may come in either order); its content must be the same (the
  recording's secret placeholders standing for whatever value the replay gives, consistently);
- what the RApp received (answers, progress informs, the Core's notifications) is delivered in the
  recorded order, each as soon as every request the RApp had sent before it in the recording has
  been matched: motions, which took simulated time, are answered at once;
- the requests whose number depends on the wall clock (heartbeats, the Platform directory's refresh)
  are answered from the recording whenever they come and are not compared;
- notifications are re-stamped: their `stamp` and `expires` move by the time between the recording's
  receipt and now (they would otherwise have expired).
What is not deterministic: a RApp's own wall-clock waits (behaviour periods, retry delays, a plan
monitor's deadlines measured in seconds) run as they ran, so a replay waits as long for them and may
decide differently where the original was close to a deadline; a request the original never got an
answer to waits out its own timeout.
"""
from __future__ import annotations

import asyncio
import json
import secrets
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from spade.behaviour import CyclicBehaviour
from spade.message import Message

from agents.base import RappAgent
from agents.messages import AclInfo, bare
from agents.tracing import BLOBS, BODIES, PACKAGES, inflate, is_placeholder, read_trace
from ontology import acl
from ontology.package import build_package_bytes, unpack_package
from ontology.spawn import RobotInfo, SpawnSpec
from ontology.trace import RecordKind, StructureEvent
from xmpp_server.credentials import generate_password

# sent as often as the wall clock says: answered from the recording, never compared
TIMED = frozenset({("core", "heartbeat"), ("platform-directory", "list_platforms")})
OPENING = frozenset(p.value for p in acl.OPENING)
FIRST_MESSAGE_S = 90.0  # the Dynamic Agent's start: a Core waits its login (20 s) and import (10 s) as long


class RecordingError(ValueError):
    """A run folder that cannot be replayed (no recording, no such run, no package)."""


@dataclass
class Exchanged:
    """One message of the recorded run, as its Dynamic Agent sent or received it."""

    dir: str  # send | recv
    peer: str  # bare JID
    performative: str
    ontology: str
    action: str
    conversation_id: str
    message_id: str
    in_reply_to: str
    feedback: bool
    body: str
    t: float
    index: int = 0  # in the exchange
    n: int = 0  # 1-based among the exchange's messages that are not TIMED (what a divergence names)

    @property
    def key(self) -> tuple[str, str, str, str]:
        return self.peer, self.performative, self.ontology, self.action

    @property
    def timed(self) -> bool:
        return (self.ontology, self.action) in TIMED

    def describe(self, content: str | None = None) -> str:
        text = self.body if content is None else content
        return (f"{self.performative} {self.ontology}/{self.action} "
                f"{'to' if self.dir == 'send' else 'from'} {self.peer.split('@')[0]}: {_short(text)}")


@dataclass
class RecordedRun:
    """One Dynamic Agent run of a recording."""

    run_dir: Path
    index: int  # 1-based among the recording's runs
    runs: int
    dynamic: str  # its JID
    core: str
    platform: str
    rapp: str
    version: str
    params: dict
    robot: RobotInfo | None
    package: Path | None
    exchange: list[Exchanged]
    wall_s: float  # from its spawn to its Core's end record
    trusted_only: bool  # its own side was not recorded: order from its peers' records

    @property
    def domain(self) -> str:
        return self.dynamic.split("@", 1)[1]

    @property
    def peers(self) -> list[str]:
        return sorted({e.peer for e in self.exchange} | {self.core, self.platform})


def _bodies(path: Path, blobs: Path) -> list[dict]:
    out = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                rec = json.loads(line)
                if isinstance(rec, dict) and rec.get("kind") == "body" and isinstance(rec.get("body"), str):
                    rec["body"] = inflate(rec["body"], blobs)
                    out.append(rec)
            except (ValueError, OSError):
                continue
    return out


def load_recording(run_dir: str | Path, run: int | None = None) -> RecordedRun:
    """The recorded Dynamic Agent run number `run` (1-based; default the last) of a run folder."""
    d = Path(run_dir)
    if not (d / "trace.jsonl").exists():
        raise RecordingError(f"{d} holds no trace.jsonl: not a run folder")
    if not (d / BODIES).exists():
        raise RecordingError(f"{d} holds no {BODIES}: the run was not recorded (rapp run without --no-record)")
    records = read_trace(d / "trace.jsonl")
    spawns = [r for r in records if r.get("kind") == RecordKind.STRUCTURE and r.get("event") == StructureEvent.SPAWN
              and not r.get("origin") and r.get("dynamic")]
    if not spawns:
        raise RecordingError(f"{d}: no Dynamic Agent was started in this run")
    n = len(spawns) if run is None else run
    if not 1 <= n <= len(spawns):
        raise RecordingError(f"{d} has {len(spawns)} RApp run(s); no run {run}")
    spawn = spawns[n - 1]
    dyn, core = bare(spawn["dynamic"]), bare(spawn["agent"])
    downloads = [r for r in records if r.get("event") == StructureEvent.DOWNLOAD and bare(r.get("agent", "")) == core
                 and not r.get("origin") and r["t"] <= spawn["t"]]
    package = None
    if downloads and downloads[-1].get("sha256"):
        p = d / PACKAGES / f"{downloads[-1]['sha256']}.rapp"
        package = p if p.exists() else None
    ends = [r for r in records if r.get("event") == StructureEvent.ENDED and bare(r.get("dynamic", "")) == dyn
            and not r.get("origin")]
    registers = [r for r in records if r.get("event") == StructureEvent.REGISTER and bare(r.get("agent", "")) == core
                 and r.get("platform")]
    platform = bare(registers[-1]["platform"]) if registers else f"platform@{dyn.split('@', 1)[1]}"
    exchange, trusted_only = _exchange(_bodies(d / BODIES, d / BLOBS), dyn)
    robot = RobotInfo.model_validate(spawn["robot"]) if spawn.get("robot") else None
    return RecordedRun(d, n, len(spawns), dyn, core, platform, spawn.get("rapp", ""), spawn.get("version", ""),
                       spawn.get("params") or {}, robot, package, exchange,
                       round((ends[0]["t"] if ends else records[-1]["t"]) - spawn["t"], 3), trusted_only)


def _exchange(bodies: list[dict], dyn: str) -> tuple[list[Exchanged], bool]:
    """The Dynamic Agent's messages in its own order (its records, as its relay wrote them), each
    with the content its trusted peer recorded where there is one (else its own record's)."""
    trusted = {}
    for b in bodies:
        if not b.get("origin") and bare(b["agent"]) != dyn and dyn in (bare(b["sender"]), bare(b["receiver"])):
            trusted.setdefault(b.get("message_id") or id(b), b)
    own = [b for b in bodies if bare(b["agent"]) == dyn]
    trusted_only = not own
    if trusted_only:  # its side not recorded: its peers' records, by time
        own = sorted(trusted.values(), key=lambda b: b["t"])
    out, seen = [], set()
    for b in own:
        mine = bare(b["sender"]) == dyn
        mid = b.get("message_id", "")
        if (mine, mid) in seen and mid:
            continue  # sent again (a resend): the same message
        seen.add((mine, mid))
        peer_rec = trusted.get(mid) if mid else None
        body = peer_rec["body"] if peer_rec is not None else b["body"]
        out.append(Exchanged("send" if mine else "recv", bare(b["receiver"] if mine else b["sender"]),
                             b.get("performative", ""), b.get("ontology", ""), b.get("action", ""),
                             b.get("conversation_id", ""), mid, b.get("in_reply_to", ""), bool(b.get("feedback")),
                             body, b["t"], len(out)))
    n = 0
    for e in out:
        n += not e.timed
        e.n = n
    return out, trusted_only


def list_runs(run_dir: str | Path) -> list[str]:
    records = read_trace(Path(run_dir) / "trace.jsonl")
    return [f"{i}: {r.get('rapp')} {r.get('version')} ({bare(r['dynamic'])})" for i, r in enumerate(
        (r for r in records if r.get("event") == StructureEvent.SPAWN and not r.get("origin") and r.get("dynamic")), 1)]


def save_recording(run_dir: str | Path, dest: str | Path) -> list[str]:
    """What a replay needs of a run folder, copied to `dest` (a RApp's tests/recording): the trace,
    the message bodies (secrets already placeholders), the kept packages and result.json; never the
    run's system/ folder (its agents' credentials). The files copied."""
    src, dest = Path(run_dir), Path(dest)
    load_recording(src)  # a clear error if it cannot be replayed
    dest.mkdir(parents=True, exist_ok=True)
    copied = []
    for name in ("trace.jsonl", BODIES, "result.json"):
        if (src / name).exists():
            shutil.copyfile(src / name, dest / name)
            copied.append(name)
    for sub, pattern in ((PACKAGES, "*.rapp"), (BLOBS, "*")):
        if (src / sub).is_dir():
            (dest / sub).mkdir(exist_ok=True)
            files = sorted((src / sub).glob(pattern))
            for p in files:
                shutil.copyfile(p, dest / sub / p.name)
            copied.append(f"{sub}/ ({len(files)} files)")
    return copied


# -- comparing ------------------------------------------------------------------------------------
def _parse(text: str) -> Any:
    try:
        return json.loads(text) if text else None
    except ValueError:
        return text


def first_difference(recorded: Any, actual: Any, secrets_: dict[str, Any], path: str = "") -> str | None:
    """Where `actual` (the replay's content) differs from `recorded` (None: nowhere); a recorded
    placeholder matches any value, the same one each time (`secrets_` remembers it)."""
    if is_placeholder(recorded):
        if recorded in secrets_ and secrets_[recorded] != actual:
            return f"{path or 'content'}: the secret {recorded} stood for another value before"
        secrets_[recorded] = actual
        return None
    if isinstance(recorded, dict) and isinstance(actual, dict):
        for k in sorted(set(recorded) | set(actual)):
            if k not in actual:
                return f"{path}.{k}: in the recording only"
            if k not in recorded:
                return f"{path}.{k}: in the replay only"
            diff = first_difference(recorded[k], actual[k], secrets_, f"{path}.{k}")
            if diff:
                return diff
        return None
    if isinstance(recorded, list) and isinstance(actual, list):
        if len(recorded) != len(actual):
            return f"{path or 'content'}: {len(actual)} items, the recording {len(recorded)}"
        for i, (a, b) in enumerate(zip(recorded, actual)):
            diff = first_difference(a, b, secrets_, f"{path}[{i}]")
            if diff:
                return diff
        return None
    if recorded != actual or type(recorded) is not type(actual) and not (
            isinstance(recorded, (int, float)) and isinstance(actual, (int, float))):
        return f"{path or 'content'}: {_short(json.dumps(actual))} in the replay, {_short(json.dumps(recorded))} recorded"
    return None


def _substituted(value: Any, secrets_: dict[str, Any]) -> Any:
    if is_placeholder(value):
        return secrets_.get(value, value)
    if isinstance(value, dict):
        return {k: _substituted(v, secrets_) for k, v in value.items()}
    if isinstance(value, list):
        return [_substituted(v, secrets_) for v in value]
    return value


def _short(text: str, n: int = 300) -> str:
    text = text if isinstance(text, str) else json.dumps(text)
    return text if len(text) <= n else text[:n] + f"... [+{len(text) - n} chars]"


# -- the script -----------------------------------------------------------------------------------
@dataclass
class Divergence:
    kind: str  # unexpected | different | missing | stalled | failed
    text: str
    replay: str = ""
    recorded: str = ""
    position: int = 0  # the recorded message it concerns (1-based in the Dynamic Agent's exchange)

    def __str__(self) -> str:
        lines = [f"first divergence ({self.kind}) at message {self.position} of the RApp's exchange: {self.text}"]
        if self.replay:
            lines.append(f"  replay:   {self.replay}")
        if self.recorded:
            lines.append(f"  recorded: {self.recorded}")
        return "\n".join(lines)


class Script:
    """The recorded exchange, followed as the replay goes (see the module's doc)."""

    def __init__(self, run: RecordedRun, deliver):
        self.run, self.deliver = run, deliver  # deliver(Exchanged, conversation_id, in_reply_to, body)
        self.sends = [e for e in run.exchange if e.dir == "send" and not e.timed and e.performative != "chat"]
        self.recvs = [e for e in run.exchange if e.dir == "recv"]
        self.timed_convs = {e.conversation_id: e for e in run.exchange if e.dir == "send" and e.timed}
        self.matched: set[int] = set()  # indexes of matched sends
        self.next_recv = 0
        self.convs: dict[str, str] = {}  # recorded conversation -> the replay's
        self.ids: dict[str, str] = {}  # recorded message id -> the replay's
        self.secrets: dict[str, Any] = {}
        self.divergence: Divergence | None = None
        self.answered = 0
        self.progress_at = time.monotonic()
        self._seen_ids: set[str] = set()
        # where each recorded request was done: the index of its final answer (or its own, expecting none);
        # a request may be matched ahead of an earlier one only if that one was still open when it was sent
        final = {p.value for p in acl.FINAL}
        answers = {}
        for e in run.exchange:
            if e.dir == "recv" and e.performative in final and not e.feedback:
                answers.setdefault(e.conversation_id, e.index)
        self.done_at = {s.index: (answers.get(s.conversation_id, len(run.exchange)) if s.performative in OPENING
                                  else s.index) for s in self.sends}
        self._by_key: dict[tuple, list[Exchanged]] = {}  # unmatched sends of each kind, in order
        for e in self.sends:
            self._by_key.setdefault(e.key, []).append(e)
        self._low = 0  # position in self.sends of the first unmatched send
        self._timed_answers: dict[tuple, list[Exchanged]] = {}  # the first timed request's answers, per kind
        for conv, e in self.timed_convs.items():
            if e.key not in self._timed_answers:
                self._timed_answers[e.key] = [r for r in self.recvs if r.conversation_id == conv]

    def _first_unmatched(self) -> Exchanged | None:
        while self._low < len(self.sends) and self.sends[self._low].index in self.matched:
            self._low += 1
        return self.sends[self._low] if self._low < len(self.sends) else None

    def on_send(self, msg: Message, peer: str) -> None:
        info = AclInfo.of(msg)
        if self.divergence is not None or (info.reply_with and info.reply_with in self._seen_ids):
            return  # after a divergence nothing more is followed; a resent message is the same one
        self._seen_ids.add(info.reply_with)
        key = (peer, info.performative or "chat", info.ontology, info.action)
        if (info.ontology, info.action) in TIMED:
            self._timed(key, info)
            return
        candidates = self._by_key.get(key) or []
        first = self._first_unmatched()
        actual = _parse(msg.body or "")
        if not candidates:
            self.diverge("unexpected", "the RApp sent a request the recording does not have",
                          _describe(key, msg.body or ""), first.describe() if first else "(nothing more)",
                          first.n if first else len(self.run.exchange))
            return
        rec = candidates[0]
        skipped = None
        for e in self.sends[self._low:]:  # the unmatched ones before it (requests in flight together: few)
            if e.index >= rec.index:
                break
            if e.index not in self.matched and self.done_at[e.index] < rec.index:
                skipped = e
                break
        if skipped is not None:  # the recording had that one done before this one was sent
            self.diverge("unexpected", "the RApp sent a request the recording has only after another one",
                          _describe(key, msg.body or ""), skipped.describe(), skipped.n)
            return
        diff = first_difference(_parse(rec.body), actual, self.secrets)
        if diff:
            self.diverge("different", diff, _describe(key, msg.body or ""), rec.describe(), rec.n)
            return
        self.matched.add(rec.index)
        candidates.pop(0)
        self.convs[rec.conversation_id] = info.conversation_id
        if rec.message_id:
            self.ids[rec.message_id] = info.reply_with
        self.progress_at = time.monotonic()
        self.pump()

    def _timed(self, key, info: AclInfo) -> None:
        """Answered with the recording's answers to the first request of its kind (none: a heartbeat)."""
        for e in self._timed_answers.get(key, []):
            self.deliver(e, info.conversation_id, info.reply_with, self._body(e))

    def pump(self) -> None:
        """Deliver what the RApp received next in the recording, as far as it may be."""
        while self.divergence is None and self.next_recv < len(self.recvs):
            e = self.recvs[self.next_recv]
            if e.conversation_id in self.timed_convs:
                self.next_recv += 1  # delivered with its timed request
                continue
            first = self._first_unmatched()
            if first is not None and first.index < e.index:
                return
            self.next_recv += 1
            self.answered += 1
            self.progress_at = time.monotonic()
            self.deliver(e, self.convs.get(e.conversation_id, e.conversation_id),
                         self.ids.get(e.in_reply_to, e.in_reply_to), self._body(e))

    def _body(self, e: Exchanged) -> str:
        value = _parse(e.body)
        if isinstance(value, (dict, list)):
            value = _substituted(value, self.secrets)
            if (e.ontology, e.action) == ("core", "notification") and isinstance(value, dict):
                _restamp(value.get("notification"), time.time() - e.t)
            return json.dumps(value)
        return e.body

    def blocked_on(self) -> Exchanged | None:
        """The recorded request the RApp has not sent and the next delivery waits for."""
        first = self._first_unmatched()
        if self.next_recv >= len(self.recvs) or first is None:
            return first
        return first if first.index < self.recvs[self.next_recv].index else None

    def unanswered(self) -> Exchanged | None:
        """A request the replay matched whose answer the recording does not have (it ended first)."""
        end = len(self.run.exchange)
        return next((s for s in self.sends if s.index in self.matched and s.performative in OPENING
                     and self.done_at[s.index] == end), None)

    def stall_limit(self, s: Exchanged, floor_s: float) -> float:
        """How long the RApp may take to send `s`: twice what it took in the recording, and floor_s more;
        its first message FIRST_MESSAGE_S at least (a sandboxed process's start and imports, under load)."""
        if not self.matched:
            return max(FIRST_MESSAGE_S, floor_s)
        before = next((e for e in reversed(self.run.exchange[:s.index]) if not e.timed), None)
        gap = s.t - before.t if before else 0.0
        return 2 * max(gap, 0.0) + floor_s

    def finish(self) -> Divergence | None:
        if self.divergence is None:
            left = [s for s in self.sends if s.index not in self.matched]
            if left:
                self.diverge("missing", f"the RApp ended without sending {len(left)} request(s) of the recording",
                              "", left[0].describe(), left[0].n)
        return self.divergence

    def diverge(self, kind: str, text: str, replay: str, recorded: str, position: int) -> None:
        if self.divergence is None:
            self.divergence = Divergence(kind, text, replay, recorded, position)


def _describe(key, body: str) -> str:
    peer, perf, ont, action = key
    return f"{perf} {ont}/{action} to {peer.split('@')[0]}: {_short(body)}"


def _restamp(note: Any, shift: float) -> None:
    if isinstance(note, dict):
        for k in ("stamp", "expires"):
            if isinstance(note.get(k), (int, float)):
                note[k] = note[k] + shift


# -- the agents -----------------------------------------------------------------------------------
class _TakeAll(CyclicBehaviour):
    """Every message to a stand-in peer goes to the script at once."""

    def __init__(self, on_message):
        super().__init__()
        self.on_message = on_message

    def match(self, msg: Message) -> bool:
        return True

    def take_now(self, msg: Message) -> asyncio.Future:
        self.on_message(msg)
        done = asyncio.get_running_loop().create_future()
        done.set_result(None)
        return done

    async def run(self) -> None:
        msg = await self.receive(timeout=0.5)
        if msg is not None:
            self.take_now(msg)


class StandIn(RappAgent):
    """A peer of the recorded Dynamic Agent (its Core, Platform, Cloud Agent), answering from the recording."""

    def __init__(self, name: str, settings, script_ref: list):
        super().__init__(name, settings, password=generate_password())
        self._script_ref = script_ref

    async def setup(self) -> None:
        self.activate("replay", _TakeAll(lambda msg: self._script_ref[0].on_send(msg, self.address)))


@dataclass
class ReplayResult:
    recording: RecordedRun
    divergence: Divergence | None
    requests: int  # the RApp's requests matched
    delivered: int  # the recorded messages it was given
    wall_s: float  # the replay, from its server's start to the RApp's end
    end: str = ""  # the RApp's last task status (Finished, Error ...)
    log: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.divergence is None

    def summary(self) -> str:
        r = self.recording
        head = (f"replay of {r.rapp} {r.version} (run {r.index} of {r.runs}, {r.dynamic.split('@')[0]}) against "
                f"{r.run_dir}: {self.requests} of {len([e for e in r.exchange if e.dir == 'send' and not e.timed])} "
                f"requests matched, {self.delivered} recorded messages given, in {self.wall_s:.1f} s "
                f"(the original {r.wall_s:.1f} s)")
        if self.divergence is None:
            return head + "\nno divergence" + (f" (the RApp ended {self.end})" if self.end else "")
        return head + "\n" + str(self.divergence)


async def replay(run_dir: str | Path, *, rapp_dir: str | Path | None = None, run: int | None = None,
                 mode: str = "process", stall_s: float = 10.0, timeout_s: float = 600.0,
                 trace_file: str | Path | None = None) -> ReplayResult:
    """Replay a recorded RApp run (see the module's doc). `rapp_dir`: a changed RApp's source folder
    instead of the recorded package; `mode`: the Dynamic Agent as a sandboxed process ("process", as
    a Core runs it) or a task of this process ("inprocess"); `stall_s`: how long, beyond twice the
    recorded time, the RApp may take to send the request the recording has next."""
    from agents.process import Limits, spawn_agent
    from agents.sandbox import Sandbox
    from agents.warm_pool import WarmPool
    from xmpp_server import EmbeddedServer

    rec = load_recording(run_dir, run)
    if rapp_dir is not None:
        data = await asyncio.to_thread(build_package_bytes, rapp_dir)
    elif rec.package is not None:
        data = rec.package.read_bytes()
    else:
        raise RecordingError(f"{rec.run_dir}: the package of {rec.rapp} was not kept ({PACKAGES}/); "
                             "give the RApp's folder (--rapp DIR)")
    t0 = time.monotonic()
    work = Path(tempfile.mkdtemp(prefix="rapp-replay-"))
    server = EmbeddedServer(domain=rec.domain, db=work / "xmpp.db")
    stand_ins: list[StandIn] = []
    process = None
    script_ref: list[Script] = []
    sandbox = Sandbox() if mode == "process" else None
    # a warm worker imports the runtime (about a second) while the server and the stand-ins start
    pool = WarmPool(work, server.settings(trace_file=trace_file, credentials_dir=work / "credentials"), size=1,
                    sandbox=sandbox) if sandbox is not None else None
    try:
        if pool is not None:
            pool.start()
        started = await asyncio.gather(asyncio.to_thread(unpack_package, data, work / "run" / "package"),
                                       server.astart(), return_exceptions=True)  # both ended before the clean-up
        failed = next((r for r in started if isinstance(r, BaseException)), None)
        if failed is not None:
            raise failed
        settings = server.settings(trace_file=trace_file, credentials_dir=work / "credentials")
        if pool is not None and settings != pool.settings:  # the server took another port: the worker cannot reach it
            await pool.close()
            pool = None
        loop = asyncio.get_running_loop()

        def deliver(e: Exchanged, conv: str, in_reply_to: str, body: str) -> None:
            agent = next((a for a in stand_ins if a.address == e.peer), None)
            if agent is None:
                return
            meta = {acl.PERFORMATIVE: e.performative, acl.CONVERSATION_ID: conv, acl.REPLY_WITH: acl.new_id("m")}
            if e.ontology:
                meta[acl.ONTOLOGY] = e.ontology
            if e.action:
                meta[acl.ACTION] = e.action
            if in_reply_to:
                meta[acl.IN_REPLY_TO] = in_reply_to
            if e.feedback:
                meta[acl.FEEDBACK] = "1"
            msg = Message(to=rec.dynamic, body=body, metadata=meta)
            loop.create_task(agent.send(msg))

        script = Script(rec, deliver)
        script_ref.append(script)
        stand_ins = [StandIn(p.split("@")[0], settings, script_ref) for p in rec.peers]
        await asyncio.gather(*(a.start(auto_register=True) for a in stand_ins))
        script.pump()  # anything the RApp received before its first request
        spec = SpawnSpec(kind="dynamic", name=rec.dynamic.split("@")[0], password=generate_password(),
                         package_dir="", core=rec.core, platform=rec.platform,
                         token="replay-" + secrets.token_urlsafe(16), params=rec.params, robot=rec.robot)
        process = spawn_agent(spec, work / "run", settings, mode=mode, limits=Limits(), sandbox=sandbox, pool=pool)
        await process.start()
        if pool is not None:
            await pool.close()  # its one worker is the run's now: no refill
        ended = asyncio.ensure_future(process.wait())
        deadline = time.monotonic() + timeout_s
        while not ended.done():
            await asyncio.wait({ended}, timeout=0.1)
            if script.divergence is not None:
                break
            waiting = script.blocked_on()
            if waiting is not None and time.monotonic() - script.progress_at > script.stall_limit(waiting, stall_s):
                open_ = script.unanswered()
                text = ("the RApp waits for the answer to a request the recording has none for (the original run "
                        f"ended while it waited): {open_.describe()}" if open_ is not None else
                        "the RApp has not sent the request the recording has next")
                script.diverge("stalled", text, "", waiting.describe(), waiting.n)
                break
            if time.monotonic() > deadline:
                script.diverge("stalled", f"the replay did not end within {timeout_s:g} s", "", "", 0)
                break
        divergence = script.finish() if ended.done() else script.divergence
        end = _last_status(rec, script)
        return ReplayResult(rec, divergence, len(script.matched), script.answered, round(time.monotonic() - t0, 3), end)
    finally:
        if process is not None:
            try:
                await process.stop(grace=1.0)
            except Exception:  # noqa: BLE001 - best effort: the replay's result stands
                pass
        if pool is not None:
            await pool.close()
        await asyncio.gather(*(a.stop() for a in stand_ins), return_exceptions=True)
        await asyncio.to_thread(server.close)
        shutil.rmtree(work, ignore_errors=True)


def _last_status(rec: RecordedRun, script: Script) -> str:
    states = [_parse(s.body) for s in script.sends if s.index in script.matched and s.action == "task_status"]
    states = [s.get("state") for s in states if isinstance(s, dict)]
    return states[-1] if states else ""


__all__ = ["replay", "load_recording", "list_runs", "save_recording", "ReplayResult", "Divergence", "RecordingError",
           "first_difference", "Script"]
