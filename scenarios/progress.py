"""Live progress of a run, read from its trace file as it grows: the Core's state, the RApp's FSM
states, structure changes (spawn, hand-off, cloud agents, resume), every chat line, the RApp's own
progress records and the robot's pose.

On a terminal it is a compact `rich` panel redrawn in place; otherwise (a log, CI, a pipe) or with
`live=False` plain lines (PlainLines): the Core's states, the RApp's own FSM states, structure changes,
chat and the RApp's progress as it moves on; the RApp's nested steps (a walk's re-localizations) and
repeated progress of one step are folded into a status line every half minute, and their totals
are printed at the end.

    view = RunView()                  # optional: the same state feeds scenarios.watch's page
    follower = asyncio.create_task(follow(trace_path, pose=lambda: robot.pose, view=view))
    ...
    follower.cancel()                 # prints the last lines / the final panel
"""
from __future__ import annotations

import asyncio
import json
import math
import sys
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path

from rich.console import Console, Group
from rich.live import Live
from rich.panel import Panel
from rich.progress_bar import ProgressBar
from rich.table import Table
from rich.text import Text

from ontology.trace import CHAT, Direction, RecordKind, StructureEvent, parse_record

_E = StructureEvent
SHOWN = {_E.SPAWN, _E.HANDOFF, _E.CLOUD_SPAWN, _E.CLOUD_DESTROY, _E.CLOUD_LOST, _E.ENDED, _E.DESTROY, _E.RESUME,
         _E.CATALOGUE_CHANGED}
PROGRESS = "progress"  # the kind of a RApp's progress record: fraction (0..1 or null), text


def _short(address) -> str:
    return str(address or "").split("@")[0]


def progress_of(rec: dict) -> tuple[float | None, str] | None:
    """(fraction, text) of a well-formed progress record, else None."""
    if rec.get("kind") != PROGRESS:
        return None
    fraction, text = rec.get("fraction"), rec.get("text", "")
    if fraction is not None and (isinstance(fraction, bool) or not isinstance(fraction, (int, float))
                                 or not 0.0 <= fraction <= 1.0):
        return None
    return (None if fraction is None else float(fraction)), str(text)


def is_shown_record(rec: dict) -> bool:
    """A record of ontology.trace (or a progress record, which it may not list yet)."""
    if progress_of(rec) is not None:
        return True
    try:
        parse_record(rec)
    except ValueError:
        return False
    return True


def request_pass(rec: dict) -> bool:
    """A state of a request's own pass (the Platform's fig. 6 FSM, the Core's s9): not the run's to show."""
    fsm = str(rec.get("fsm", ""))
    return bool(rec.get("conversation_id")) or fsm == "platform" or fsm.startswith(("platform.", "core."))


def describe(rec: dict) -> str | None:
    """One line for a trace record worth showing, else None."""
    kind, agent = rec.get("kind"), _short(rec.get("agent"))
    if kind == RecordKind.STATE and request_pass(rec):
        return None
    if kind == RecordKind.STATE and rec.get("event") == "enter":
        who = "core" if rec.get("fsm") == "core" else f"rapp {rec.get('fsm')}"
        return f"{who}: {rec.get('state')}"
    if kind == RecordKind.STRUCTURE and rec.get("event") in SHOWN:
        detail = rec.get("dynamic") or rec.get("cloud") or rec.get("to") or rec.get("reason") or ""
        return f"{agent}: {rec['event']} {_short(detail)}".rstrip()
    if kind == RecordKind.MESSAGE and rec.get("performative") == CHAT and rec.get("dir") == Direction.SEND:
        return f"chat {agent} -> {_short(rec.get('receiver'))}: {rec.get('content', '')}"
    progress = progress_of(rec)
    if progress is not None:
        fraction, text = progress
        return f"progress {agent}: {'' if fraction is None else f'{fraction:.0%} '}{text}".rstrip()
    return None


@dataclass
class RunView:
    """What a run looks like now, from its trace records and the robot's pose: the live panel
    draws it, scenarios.watch serves it."""

    core: str = ""
    rapp: str = ""  # the RApp's FSM name
    rapp_state: str = ""
    pose: tuple[float, float, float] | None = None
    fraction: float | None = None
    progress_text: str = ""
    chat: deque = field(default_factory=lambda: deque(maxlen=5))  # "sender -> receiver: text"
    events: deque = field(default_factory=lambda: deque(maxlen=3))  # recent structure events
    started: float = field(default_factory=time.monotonic)

    def apply(self, rec: dict) -> None:
        kind = rec.get("kind")
        if kind == RecordKind.STATE and request_pass(rec):
            return
        if kind == RecordKind.STATE and rec.get("event") == "enter":
            if rec.get("fsm") == "core":
                self.core = str(rec.get("state"))
            else:
                self.rapp, self.rapp_state = str(rec.get("fsm")), str(rec.get("state"))
        elif kind == RecordKind.STRUCTURE and rec.get("event") in SHOWN:
            self.events.append(describe(rec))
            if rec.get("event") == _E.SPAWN:  # a new task: its progress starts afresh
                self.fraction, self.progress_text = None, ""
        elif kind == RecordKind.MESSAGE and rec.get("performative") == CHAT and rec.get("dir") == Direction.SEND:
            self.chat.append(f"{_short(rec.get('agent'))} -> {_short(rec.get('receiver'))}: {rec.get('content', '')}")
        elif (progress := progress_of(rec)) is not None:
            self.fraction, self.progress_text = progress

    def elapsed(self) -> float:
        return time.monotonic() - self.started

    def snapshot(self) -> dict:
        """As JSON data (the watch page's side panel)."""
        return {"core": self.core, "rapp": self.rapp, "rapp_state": self.rapp_state,
                "fraction": self.fraction, "progress_text": self.progress_text, "chat": list(self.chat),
                "events": list(self.events), "elapsed_s": round(self.elapsed(), 1)}


def pose_text(pose) -> str:
    if pose is None:
        return "-"
    x, y, th = pose
    return f"x {x:.2f}  y {y:.2f}  θ {math.degrees(th):.0f}°"


def render(view: RunView, title: str = "rapp run") -> Panel:
    """The compact panel: Core and RApp states, pose, progress, recent events and chat lines."""
    grid = Table.grid(padding=(0, 1))
    grid.add_column(style="bold cyan", no_wrap=True)
    grid.add_column(overflow="ellipsis", no_wrap=True)
    grid.add_row("Core", view.core or "-")
    grid.add_row("RApp", f"{view.rapp}: {view.rapp_state}" if view.rapp else "-")
    grid.add_row("Robot", pose_text(view.pose))
    if view.fraction is not None or view.progress_text:
        bar = Table.grid(padding=(0, 1))
        if view.fraction is not None:
            bar.add_row(ProgressBar(total=1.0, completed=view.fraction, width=20),
                        f"{view.fraction:.0%}", Text(view.progress_text, overflow="ellipsis", no_wrap=True))
        else:
            bar.add_row(Text(view.progress_text, overflow="ellipsis", no_wrap=True))
        grid.add_row("Progress", bar)
    if view.events:
        grid.add_row("Events", Group(*(Text(e, overflow="ellipsis", no_wrap=True) for e in view.events)))
    grid.add_row("Chat", Group(*(Text(c, overflow="ellipsis", no_wrap=True) for c in view.chat))
                 if view.chat else "-")
    return Panel(grid, title=f"{title} · {view.elapsed():.1f} s", title_align="left", expand=True)


class TraceTail:
    """The complete records appended to a trace file since the last read (several processes
    append lines; a half-written last line waits for the next read)."""

    def __init__(self, path: str | Path):
        self.path, self.offset = Path(path), 0

    def read(self) -> list[dict]:
        if not self.path.exists():
            return []
        with self.path.open("rb") as f:
            f.seek(self.offset)
            data = f.read()
        complete = data.rfind(b"\n") + 1
        self.offset += complete
        out = []
        for line in data[:complete].splitlines():
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if isinstance(rec, dict) and is_shown_record(rec):  # else skipped like a broken line
                out.append(rec)
        return out


class PlainLines:
    """A run's progress as plain lines (a log, a pipe), folded so that a long run stays readable:
    states the Core enters within one read are one line ("core: s4a_keyword -> s5_download"); of a
    RApp only its own FSM's states are lines (the first FSM it enters after a spawn), its nested FSMs'
    steps are counted; a progress record is a line when its fraction or its subject (the text before
    ':') changes, else it is folded. `status()` is a line with the pose, the latest progress and what
    was folded since the last one; `totals()` the folded steps of the whole run."""

    def __init__(self, print_line, status_every: float = 30.0):
        self.print, self.status_every = print_line, status_every
        self.top: str | None = None  # the RApp's own FSM
        self.steps: Counter = Counter()  # (fsm, state) of nested FSMs, whole run
        self.folded = 0  # records folded since the last status line
        self.progress: tuple[float | None, str] | None = None  # the last progress shown
        self.latest = ""  # the latest progress text (shown or folded)
        self.core_chain: list[str] = []
        self.last_status = -math.inf

    def batch(self, records: list[dict], now: float) -> None:
        for rec in records:
            if rec.get("kind") == RecordKind.STATE and request_pass(rec):
                continue
            if rec.get("kind") == RecordKind.STATE and rec.get("event") == "enter" and rec.get("fsm") == "core":
                self.core_chain.append(str(rec.get("state")))
                continue
            self._flush_core()
            self._one(rec)
        self._flush_core()

    def _flush_core(self) -> None:
        if self.core_chain:
            self.print(f"core: {' -> '.join(self.core_chain)}")
            self.core_chain = []

    def _one(self, rec: dict) -> None:
        kind = rec.get("kind")
        if kind == RecordKind.STRUCTURE and rec.get("event") == _E.SPAWN:
            self.top, self.progress = None, None
        if kind == RecordKind.STATE and rec.get("event") == "enter":
            fsm = str(rec.get("fsm"))
            self.top = self.top or fsm
            if fsm != self.top:
                self.steps[(fsm, str(rec.get("state")))] += 1
                self.folded += 1
                return
        progress = progress_of(rec)
        if progress is not None:
            fraction, text = progress
            self.latest = text
            shown = self.progress
            if shown is not None and shown[0] == fraction and shown[1].split(":")[0] == text.split(":")[0]:
                self.folded += 1
                return
            self.progress = progress
        text = describe(rec)
        if text:
            self.print(text)

    def status(self, now: float, pose) -> None:
        """The status line, every `status_every` seconds once something was folded (and at the start)."""
        if now - self.last_status < self.status_every or (self.folded == 0 and self.last_status > -math.inf):
            return
        self.last_status = now
        parts = [] if pose is None else [f"robot at x={pose[0]:.2f} y={pose[1]:.2f} theta={pose[2]:.2f}"]
        if self.folded:
            parts.append(f"{self.folded} steps folded" + (f", latest: {self.latest}" if self.latest else ""))
        self.folded = 0
        if parts:
            self.print("; ".join(parts))

    def totals(self) -> list[str]:
        """The nested FSMs' steps of the whole run: "n3_relocalize 1117 (l2_turn_head 380, ...)"."""
        by_fsm: dict[str, Counter] = {}
        for (fsm, state), n in self.steps.items():
            by_fsm.setdefault(fsm, Counter())[state] = n
        return [f"{fsm} {sum(c.values())} ({', '.join(f'{st} {n}' for st, n in c.most_common())})"
                for fsm, c in sorted(by_fsm.items(), key=lambda kv: -sum(kv[1].values()))]


def wants_live(out=None) -> bool:
    """The live panel only on a terminal (a log or CI gets plain lines)."""
    stream = out or sys.stdout
    return bool(getattr(stream, "isatty", lambda: False)())


async def follow(trace: str | Path, pose=None, out=None, pose_every: float = 30.0, period: float = 0.3,
                 live: bool | None = None, view: RunView | None = None, title: str = "rapp run",
                 silent: bool = False) -> None:
    """Show progress until cancelled (then what was written so far, once more, and in plain lines
    the totals of what was folded); `pose()` -> (x, y, theta) or None. `live`: the rich panel (None:
    when `out`, default stdout, is a terminal), else plain lines (PlainLines; `pose_every`: seconds
    between status lines); `silent`: neither. `view` is kept up to date in every case."""
    out = out or sys.stdout
    view = view if view is not None else RunView()
    tail, t0 = TraceTail(trace), time.monotonic()
    use_live = not silent and (wants_live(out) if live is None else live)
    lines = not silent and not use_live
    plain = PlainLines(lambda text: print(f"[{time.monotonic() - t0:6.1f}s] {text}", file=out, flush=True),
                       status_every=pose_every)

    def read_new() -> None:
        records = tail.read()
        for rec in records:
            view.apply(rec)
        if lines:
            plain.batch(records, time.monotonic())

    def sample_pose(now: float) -> None:
        p = pose() if pose is not None else None
        if p is not None:
            view.pose = tuple(float(v) for v in p[:3])
        if lines:
            plain.status(now - t0, p)

    display = None
    if use_live:  # redrawn by this task only (no refresh thread reading the view meanwhile)
        display = Live(render(view, title), console=Console(file=out), auto_refresh=False, transient=False)
        display.start()
    try:
        while True:
            read_new()
            sample_pose(time.monotonic())
            if display is not None:
                display.update(render(view, title), refresh=True)
            await asyncio.sleep(period)
    except asyncio.CancelledError:
        read_new()  # the run's last lines (destroy, resume) before it stops
        if lines and (totals := plain.totals()):
            plain.print("steps folded above, whole run: " + "; ".join(totals))
    finally:
        if display is not None:
            display.update(render(view, title), refresh=True)
            display.stop()
