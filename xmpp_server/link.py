"""A flaky link between a robot and its XMPP server: latency, jitter, loss and outages, seeded.

A TCP relay on loopback that a robot's agents (its Core and the Dynamic Agents it starts) connect
through instead of the server's own port (issue 48.4: "the simulation stops flattering").

Why a relay and not `tc netem` in a network namespace: the kernels this runs on (CI's included) are
built without sch_netem and veth, so the relay is the one fault model that runs everywhere. It acts
on the byte stream, above TCP, so each fault is the one TCP would show an application:
- delay and jitter: every chunk is held `delay ± jitter` (normal, cut at 0); order is kept (one
  stream), so a late chunk holds the ones behind it, as on a real link.
- loss: a lost segment is resent by TCP after its retransmission time-out; the relay holds a chunk
  for RTO_S (doubling while the following ones are "lost" too), which is what a loss costs a TCP
  reader. Bytes are never corrupted or dropped: TCP does not let an application see that.
- outages, two kinds: "hold" (a radio gap shorter than TCP's give-up: nothing flows, then all of it
  does) and "drop" (the access point goes: every connection is reset and new ones are refused until
  it ends, so the agents reconnect and resend what is pending).
What it cannot show: reordering between connections' packets, a half-open connection that TCP keeps
for minutes, bandwidth limits (add `tc tbf` where a kernel has it).

    link = FaultyLink(("127.0.0.1", 5222), LinkFaults.parse("delay=80ms,jitter=30ms,loss=2%,outage=5s@40s"))
    await link.start()          # link.port: connect here
    link.outage(5.0)            # or now, from a test or a scenario
    await link.stop()
"""
from __future__ import annotations

import asyncio
import contextlib
import random
import re
import time
from dataclasses import asdict, dataclass, field

RTO_S = 0.2  # Linux's minimum retransmission time-out (TCP_RTO_MIN)
KINDS = ("hold", "drop")
_UNITS = {"ms": 0.001, "s": 1.0, "": 1.0}


def _seconds(text: str, default_unit: str) -> float:
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(ms|s)?\s*", text)
    if not m:
        raise ValueError(f"{text!r}: expected a duration such as 80ms or 5s")
    return float(m.group(1)) * _UNITS[m.group(2) or default_unit]


@dataclass(frozen=True)
class LinkFaults:
    """What the link does to the bytes; `parse` reads the `--link` option's text."""
    delay_s: float = 0.0
    jitter_s: float = 0.0
    loss: float = 0.0  # share of chunks "lost" (held for a TCP resend)
    outages: tuple[tuple[float, float], ...] = ()  # (seconds after the link starts, duration)
    kind: str = "hold"  # how an outage behaves: hold or drop
    seed: int = 0

    def __post_init__(self):
        if self.delay_s < 0 or self.jitter_s < 0:
            raise ValueError("delay and jitter cannot be negative")
        if not 0.0 <= self.loss < 1.0:
            raise ValueError(f"loss {self.loss} must be a share in [0, 1)")
        if self.kind not in KINDS:
            raise ValueError(f"outage kind {self.kind!r}: one of {', '.join(KINDS)}")
        if any(at < 0 or length <= 0 for at, length in self.outages):
            raise ValueError("an outage starts at >= 0 s and lasts > 0 s")

    @classmethod
    def parse(cls, text: str, seed: int = 0) -> "LinkFaults":
        """"delay=80ms,jitter=30ms,loss=2%,outage=5s@40s,drop" (any subset, any order; `seed=N`
        overrides `seed`); "" is a perfect link."""
        kw: dict = {"seed": seed}
        outages = []
        for part in filter(None, (p.strip() for p in text.split(","))):
            key, _, value = part.partition("=")
            try:
                if key in KINDS and not value:
                    kw["kind"] = key
                elif key in ("delay", "jitter"):
                    kw[f"{key}_s"] = _seconds(value, "ms")
                elif key == "loss":
                    kw["loss"] = float(value.rstrip("%")) / (100 if value.endswith("%") else 1)
                elif key == "outage":
                    length, _, at = value.partition("@")
                    outages.append((_seconds(at or "0", "s"), _seconds(length, "s")))
                elif key == "seed":
                    kw["seed"] = int(value)
                else:
                    raise ValueError(f"unknown fault {key!r}: delay, jitter, loss, outage, hold, drop, seed")
            except ValueError as e:
                raise ValueError(f"link fault {part!r}: {e}") from None
        return cls(outages=tuple(outages), **kw)

    def describe(self) -> dict:
        """As a run's result.json names it."""
        return {**asdict(self), "outages": [list(o) for o in self.outages]}


@dataclass
class LinkStats:
    connections: int = 0
    refused: int = 0  # connections refused during a "drop" outage
    reset: int = 0  # connections cut by a "drop" outage
    chunks: int = 0
    bytes: int = 0
    lost: int = 0  # chunks held for a resend
    outages_done: list[list[float]] = field(default_factory=list)  # [start, end] in link seconds


class FaultyLink:
    """Relays connections made to `self.port` to `target`, with `faults` applied both ways."""

    def __init__(self, target: tuple[str, int], faults: LinkFaults = LinkFaults()):
        self.target, self.faults = target, faults
        self.stats = LinkStats()
        self.port = 0
        self._rng = random.Random(faults.seed)
        self._server: asyncio.base_events.Server | None = None
        self._flowing = asyncio.Event()  # cleared during a "hold" outage
        self._flowing.set()
        self._down = False  # during a "drop" outage
        self._pumps: set[asyncio.Task] = set()
        self._writers: set[asyncio.StreamWriter] = set()
        self._timers: list[asyncio.Task] = []
        self._t0 = 0.0

    @property
    def address(self) -> tuple[str, int]:
        return ("127.0.0.1", self.port)

    async def start(self) -> "FaultyLink":
        self._server = await asyncio.start_server(self._accept, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]
        self._t0 = time.monotonic()
        self._timers = [asyncio.create_task(self._scheduled(at, length)) for at, length in self.faults.outages]
        return self

    async def stop(self) -> None:
        for task in self._timers:
            task.cancel()
        if self._server is not None:
            self._server.close()
        self._cut_all()
        for task in list(self._pumps):
            task.cancel()
        await asyncio.gather(*self._pumps, return_exceptions=True)

    async def __aenter__(self) -> "FaultyLink":
        return await self.start()

    async def __aexit__(self, *exc) -> None:
        await self.stop()

    def outage(self, length_s: float, kind: str | None = None) -> asyncio.Task:
        """An outage from now, of the link's kind unless `kind` says; its task ends with it."""
        return asyncio.create_task(self._outage(length_s, kind or self.faults.kind))

    # -- faults -----------------------------------------------------------------------------
    async def _scheduled(self, at: float, length: float) -> None:
        await asyncio.sleep(max(0.0, self._t0 + at - time.monotonic()))
        await self._outage(length, self.faults.kind)

    async def _outage(self, length: float, kind: str) -> None:
        start = time.monotonic() - self._t0
        if kind == "drop":
            self._down = True
            self._cut_all()
        else:
            self._flowing.clear()
        try:
            await asyncio.sleep(length)
        finally:
            self._down = False
            self._flowing.set()
            self.stats.outages_done.append([round(start, 3), round(time.monotonic() - self._t0, 3)])

    def _cut_all(self) -> None:
        for w in list(self._writers):
            self.stats.reset += 1
            w.transport.abort()  # a reset, not a polite close: the peer sees the link die
        self._writers.clear()

    def _hold_for(self, consecutive_lost: int) -> tuple[float, int]:
        """Seconds a chunk waits, and the run of lost chunks it leaves."""
        f = self.faults
        wait = max(0.0, self._rng.gauss(f.delay_s, f.jitter_s)) if f.jitter_s else f.delay_s
        if f.loss and self._rng.random() < f.loss:
            self.stats.lost += 1
            return wait + RTO_S * 2 ** min(consecutive_lost, 6), consecutive_lost + 1
        return wait, 0

    # -- relaying ---------------------------------------------------------------------------
    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._down:
            self.stats.refused += 1
            writer.transport.abort()
            return
        try:
            up_r, up_w = await asyncio.open_connection(*self.target)
        except OSError:
            writer.transport.abort()
            return
        self.stats.connections += 1
        self._writers |= {writer, up_w}
        pumps = [asyncio.create_task(self._pump(reader, up_w)), asyncio.create_task(self._pump(up_r, writer))]
        self._pumps.update(pumps)
        try:
            await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for p in pumps:
                p.cancel()
            for w in (writer, up_w):
                self._writers.discard(w)
                w.transport.abort()
            await asyncio.gather(*pumps, return_exceptions=True)
            self._pumps.difference_update(pumps)

    async def _pump(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """One direction: read, stamp each chunk with when it may go on (never before the one ahead
        of it), write it then. Reading runs ahead of writing, as the kernel's buffers do."""
        queue: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue()
        sender = asyncio.create_task(self._send(queue, writer))
        lost, last_due = 0, 0.0
        try:
            while data := await reader.read(65536):
                wait, lost = self._hold_for(lost)
                last_due = max(time.monotonic() + wait, last_due)
                self.stats.chunks += 1
                self.stats.bytes += len(data)
                queue.put_nowait((last_due, data))
            queue.put_nowait(None)
            await sender
        except (ConnectionError, OSError):
            pass
        finally:
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, ConnectionError, OSError):
                await sender

    async def _send(self, queue: asyncio.Queue, writer: asyncio.StreamWriter) -> None:
        while (item := await queue.get()) is not None:
            due, data = item
            if (wait := due - time.monotonic()) > 0:
                await asyncio.sleep(wait)
            await self._flowing.wait()
            writer.write(data)
            await writer.drain()
        if writer.can_write_eof():
            writer.write_eof()
