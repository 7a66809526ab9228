"""RappAgent: the SPADE agent every RAPP agent derives from.

What it adds to spade.agent.Agent:
- connects to `settings.host:port` whatever the JID domain is, and start() has a time limit;
- every message sent or received is traced (agents/tracing.py) with its delivery path; a setting
  (`force_xmpp`) makes even in-process messages go through the XMPP server;
- FIPA-Request initiator: `await agent.request(to, action_model)` returns the inform content or
  raises RequestRefused / RequestFailed / NotUnderstood / RequestTimeout (agents/errors.py);
  answers are routed to the waiting call by conversation id, no behaviour needed;
- named behaviour activation (`activate`, `deactivate`, `active_behaviours`) traced as structure;
- nothing is dropped silently: a request no active behaviour takes is answered (refuse when the
  action is known but not served now, not-understood when unknown), other unmatched messages go to
  `on_unhandled`.
"""
from __future__ import annotations

import asyncio
import logging
import time
from typing import Any

from spade.agent import Agent
from spade.behaviour import CyclicBehaviour, FSMBehaviour
from spade.message import Message

from ontology import acl
from ontology import core as C
from ontology.acl import Performative
from ontology.common import Reason
from ontology.registry import Action, Content, ContentError, Progress, lookup, parse_json, validate
from xmpp_server.compat import AgentDoor, end_filter_task
from xmpp_server.ports import free_port
from xmpp_server.settings import XmppSettings
from ontology.errors import ErrorCode
from ontology.trace import RecordKind

from .errors import (AgentStartError, NotUnderstood, RequestFailed, RequestRefused,
                     RequestTimeout)
from .messages import AclInfo, bare, copy_message, is_feedback, make_message, reply_to
from .recent import RecentSet
from .stanza import message_xml, read_message, uses_form
from .tracing import CONTENT_CAP, cap, tracer_for

log = logging.getLogger("rapp.agent")
_ANSWER_VALUES = frozenset(p.value for p in acl.ANSWERS)
_OPENING_VALUES = frozenset(p.value for p in acl.OPENING)
RESEND_EVERY_S, RESEND_FOR_S = 1.0, 30.0  # pending requests after a reconnect (see _resend_pending)
FIRST_CONTACT_RESEND_S, FIRST_CONTACT_RESENDS = 1.0, 5  # a peer never heard from (_first_contact)
PEERS_KEPT = 4096  # peers remembered (_heard_from, _form_peers): a fleet's live agents, many times over
MAX_BODY = 256 * 1024  # characters; packages travel in 48 KiB chunks, nothing legitimate is larger
REPORT_CAP = MAX_BODY  # a RApp's report to its Core is traced whole: it is the run's result


class RappAgent(AgentDoor, Agent):
    """AgentDoor (xmpp_server/compat.py) checks the pins, installs the patches and turns SPADE's
    private members into the hooks below: connect_addresses, stanza_received, send."""

    def __init__(self, name: str, settings: XmppSettings | None = None, password: str | None = None):
        self.settings = settings or XmppSettings.from_env()
        super().__init__(self.settings.jid(name), password or self.settings.password_for(name),
                         port=self.settings.port, verify_security=self.settings.verify_tls)
        self.tracer = tracer_for(self.settings.trace_file)
        self._pending: dict[str, asyncio.Queue] = {}
        self._pending_peer: dict[str, str] = {}  # conversation -> bare JID asked
        self._outbox: dict[str, Message] = {}  # conversation -> the request, until answered
        # bare JIDs that send SPADE's metadata form (agents/stanza.py) / sent us anything (see
        # _first_contact); bounded, most recent kept: every RApp run brings JIDs of its own
        self._form_peers = RecentSet(PEERS_KEPT)
        self._heard_from = RecentSet(PEERS_KEPT)
        self._named: dict[str, Any] = {}
        self.unhandled: list[Message] = []  # kept, not dropped, for inspection
        self.web_url: str | None = None  # SPADE's agent page when settings.web is on

    # -- identity and lifecycle -------------------------------------------------------------
    @property
    def address(self) -> str:
        return str(self.jid.bare)

    async def start(self, auto_register: bool | None = None) -> None:
        reg = self.settings.auto_register if auto_register is None else auto_register
        self._early: list | None = []  # messages that arrive before setup() has activated behaviours
        try:
            await asyncio.wait_for(super().start(auto_register=reg), self.settings.start_timeout)
        except asyncio.TimeoutError:
            self.tracer.record(RecordKind.AGENT, event="start-failed", agent=self.address, reason="timeout")
            await self._abort_connection()
            raise AgentStartError(
                f"{self.address} could not log in to {self.settings.host}:{self.settings.port} "
                f"within {self.settings.start_timeout:.0f}s (is the XMPP server running?)") from None
        except Exception as e:
            self.tracer.record(RecordKind.AGENT, event="start-failed", agent=self.address, reason=str(e))
            await self._abort_connection()
            raise AgentStartError(f"{self.address} could not start: {type(e).__name__}: {e}") from e
        web = {}
        if self.settings.web:  # SPADE's agent page, loopback only; listening once start() returns
            await self.web.start(hostname="127.0.0.1", port=free_port("127.0.0.1"))
            self.web_url = f"http://127.0.0.1:{self.web.port}/spade"
            web = {"web": self.web_url}
        self._stopping = False
        early, self._early = self._early, None
        for msg, info in early:  # e.g. the owner's chat to a Core restarted a moment ago
            self._deliver(msg, info)
        self.client.add_event_handler("disconnected", self._on_disconnected)
        self.tracer.record(RecordKind.AGENT, event="started", agent=self.address, cls=type(self).__name__, **web)

    # -- reconnection -----------------------------------------------------------------------
    def _on_disconnected(self, _event) -> None:
        if getattr(self, "_stopping", True) or getattr(self, "_reconnecting", False):
            return
        self._reconnecting = True
        self.tracer.record(RecordKind.AGENT, event="disconnected", agent=self.address)
        self.submit(self._reconnect())

    async def _reconnect(self) -> None:
        """Log in again with back-off (0.2 s doubling to 5 s) until the server is back; with
        `settings.fallback` (other nodes of a cluster) each attempt takes the next address."""
        delay = 0.2
        addresses = self.settings.addresses()
        attempt = 0
        try:
            while not self._stopping:
                host, port = addresses[attempt % len(addresses)]
                attempt += 1
                started = asyncio.get_running_loop().create_future()
                handler = lambda _e: started.done() or started.set_result(True)  # noqa: E731
                self.client.add_event_handler("session_start", handler)
                self.reconnect_to(host, port)
                try:
                    await asyncio.wait_for(started, max(2.0, delay))
                    self._reconnected_at = time.monotonic()
                    self.tracer.record(RecordKind.AGENT, event="reconnected", agent=self.address,
                                       server=f"{host}:{port}")
                    self._resend_pending()
                    self.submit(self.on_reconnected())
                    return
                except asyncio.TimeoutError:
                    self.client.abort()
                    await asyncio.sleep(delay)
                    delay = min(delay * 2, 5.0)
                finally:
                    self.client.del_event_handler("session_start", handler)
        finally:
            self._reconnecting = False

    async def on_reconnected(self) -> None:
        """A hook: the agent is logged in again after a lost connection (its pending requests are
        being resent). A one-way message it sent as the old connection died may be lost: an agent whose
        informs carry state (the Core's pause notice) sends that state again here."""

    @property
    def reconnected_at(self) -> float:
        """time.monotonic() of the last reconnection; 0.0 before any."""
        return getattr(self, "_reconnected_at", 0.0)

    def _resend_pending(self) -> None:
        """After a reconnect, send every request still waiting for its answer again (same
        conversation): a request or its answer may have died with the old connection. Again every
        RESEND_EVERY_S while it waits, for as long as RESEND_FOR_S: the peer may come back later
        than this agent, and a server without offline storage (Prosody here) drops what is sent
        to it meanwhile. Responders answer a repeated conversation from their store, so nothing is
        executed twice."""
        convs = list(self._outbox)
        if convs:
            self.submit(self._resend_loop(convs))

    async def _resend_loop(self, convs: list[str]) -> None:
        for _ in range(int(RESEND_FOR_S / RESEND_EVERY_S)):
            waiting = [c for c in convs if c in self._outbox]
            if not waiting or self._stopping or self.client is None:
                return
            for conv in waiting:
                msg = self._outbox[conv]
                self.tracer.record(RecordKind.RESEND, agent=self.address, peer=str(msg.to), conversation_id=conv)
                self.client.send(self._stanza(msg))
            await asyncio.sleep(RESEND_EVERY_S)

    async def _abort_connection(self) -> None:
        if self.client is not None:
            try:
                self.client.disconnect()
            except Exception:  # noqa: BLE001 - best effort on a half-open connection
                pass
        self.leave_container()

    def connect_addresses(self) -> list[tuple[str, int]]:
        """Where to log in (AgentDoor): settings.host:port, then the cluster's fallback nodes."""
        return self.settings.addresses()

    async def stop(self) -> None:
        self._stopping = True
        for q in self._pending.values():
            q.put_nowait(None)  # wake waiting requests; they fail as timeouts
        await super().stop()
        await end_filter_task(self.client)
        self.leave_container()
        here = asyncio.current_task()
        for task in [t for t in self._submitted if t is not here and not t.done()]:
            task.cancel()  # e.g. a deactivated behaviour still waiting for its next message
        self.tracer.record(RecordKind.AGENT, event="stopped", agent=self.address, cls=type(self).__name__)

    @property
    def _submitted(self) -> set[asyncio.Task]:
        return self.__dict__.setdefault("_submitted_tasks", set())

    def submit(self, coro) -> asyncio.Task:
        """SPADE's submit keeps no reference to the task: a behaviour removed while it waited for a
        message was garbage-collected pending ("Task was destroyed but it is pending!" at the end of
        every run). The agent holds its tasks until they end, and cancels what is left at its stop."""
        task = super().submit(coro)
        self._submitted.add(task)
        task.add_done_callback(self._submitted.discard)
        return task

    # -- sending ----------------------------------------------------------------------------
    async def send(self, msg: Message) -> None:
        if msg.empty_sender():
            msg.sender = str(self.jid)
        to = str(msg.to)
        local = None if self.settings.force_xmpp else self.local_agent(to)
        self._trace_message("send", msg, "direct" if local else "xmpp")
        if local is not None:
            local.dispatch(copy_message(msg))
        else:
            if self.client is None:
                raise RuntimeError(f"{self.address} is not connected")
            # a str stanza is queued by slixmpp while disconnected and sent after reconnecting
            self.client.send(self._stanza(msg))

    def _stanza(self, msg: Message) -> str:
        """Compact metadata, or SPADE's form to a peer that speaks it (a plain SPADE agent)."""
        return message_xml(msg, form=bool(self._form_peers) and bare(str(msg.to)) in self._form_peers)

    # -- receiving --------------------------------------------------------------------------
    def stanza_received(self, node):
        msg = read_message(node)
        if uses_form(msg):
            self._form_peers.add(bare(msg.sender))
        if node["type"] == "error":
            # the server bounced a message of ours (peer gone); ejabberd returns it whole, and read
            # as a message it would be a request "from" the peer: never delivered, only traced
            self.tracer.record(RecordKind.DROPPED, agent=self.address, sender=bare(msg.sender),
                               conversation_id=AclInfo.of(msg).conversation_id,
                               reason=f"undeliverable: {node['error']['condition'] or 'error'}")
            return []
        return self._route(msg, "xmpp")

    def _first_contact(self, conv: str, msg: Message, sent: int = 0) -> None:
        """A request to a peer that has never sent us anything is sent again every
        FIRST_CONTACT_RESEND_S until the peer is heard from: a server without offline storage
        (Prosody) silently drops what reaches an agent that has logged in but whose presence it
        has not processed yet (seen when agents start together). Responders answer a repeated
        conversation from their store, so nothing runs twice; peers already heard from are not
        resent to (their slow actions would only get duplicates)."""
        def again() -> None:
            if (self._outbox.get(conv) is not msg or bare(str(msg.to)) in self._heard_from
                    or self.client is None or self._stopping):
                return
            self.tracer.record(RecordKind.RESEND, agent=self.address, peer=str(msg.to), conversation_id=conv)
            self.client.send(self._stanza(msg))
            self._first_contact(conv, msg, sent + 1)
        if sent < FIRST_CONTACT_RESENDS:
            asyncio.get_running_loop().call_later(FIRST_CONTACT_RESEND_S, again)

    def dispatch(self, msg: Message):
        return self._route(msg, "direct")

    def _route(self, msg: Message, path: str):
        self._heard_from.add(bare(msg.sender))
        info = AclInfo.of(msg)
        self._trace_message("recv", msg, path, info)
        return self._deliver(msg, info)

    def _deliver(self, msg: Message, info: AclInfo):
        if len(msg.body or "") > MAX_BODY:
            return [self.submit(self._too_large(msg, info))]
        if info.performative in _ANSWER_VALUES and info.conversation_id in self._pending:
            self._pending[info.conversation_id].put_nowait(msg)
            return []
        early = getattr(self, "_early", None)
        if early is not None:  # still starting: held until setup() has activated the behaviours
            early.append((msg, info))
            return []
        tasks, taken = [], False
        for behaviour in self.behaviours:
            if _accepts(behaviour, msg):
                taken = True
                direct = getattr(behaviour, "take_now", None)  # responders: no queue hop
                if direct is not None:
                    tasks.append(direct(msg))
                else:  # SPADE's enqueue spawns a task per message to put into an unbounded queue
                    behaviour.queue.put_nowait(msg)
        if not taken:
            tasks.append(self.submit(self._unhandled(msg, info)))
        return tasks

    async def _unhandled(self, msg: Message, info: AclInfo) -> None:
        if info.performative in _OPENING_VALUES:
            try:
                lookup(info.ontology, info.action)
            except ContentError as e:
                await self.send(reply_to(msg, Reason(reason=str(e), code=ErrorCode.UNKNOWN_ACTION),
                                         Performative.NOT_UNDERSTOOD))
                return
            reason = self.not_serving_reason(info)
            await self.send(reply_to(msg, Reason(reason=reason, code=ErrorCode.NOT_SERVING), Performative.REFUSE))
            return
        await self.on_unhandled(msg, info)

    async def _too_large(self, msg: Message, info: AclInfo) -> None:
        reason = f"message of {len(msg.body)} characters exceeds the limit of {MAX_BODY}"
        if info.performative in _OPENING_VALUES:
            msg.body = ""
            await self.send(reply_to(msg, Reason(reason=reason, code=ErrorCode.TOO_LARGE), Performative.NOT_UNDERSTOOD))
        else:
            self.tracer.record(RecordKind.DROPPED, agent=self.address, sender=bare(msg.sender), reason=reason)

    def not_serving_reason(self, info: AclInfo) -> str:
        """Why a known action is refused when no active behaviour serves it (override to explain)."""
        return f"{self.address} does not serve {info.ontology}/{info.action} now"

    async def on_unhandled(self, msg: Message, info: AclInfo) -> None:
        """A non-request message no behaviour took (late answer, chat text). Kept, logged."""
        self.unhandled.append(msg)
        del self.unhandled[:-200]
        self.tracer.record(RecordKind.DROPPED, agent=self.address, sender=bare(msg.sender),
                           performative=info.performative, conversation_id=info.conversation_id,
                           reason="no behaviour matched")

    # -- FIPA-Request initiator -------------------------------------------------------------
    def holds_requests_to(self, peer: str) -> bool:
        """True while requests to `peer` must not time out (a paused task's held motions)."""
        return False

    async def request(self, to: str, content: Action, *, timeout: float = 10.0,
                      performative: Performative = Performative.REQUEST,
                      retries: int | None = None, on_feedback=None) -> Content:
        """Send a request and wait for the final answer (agree is noted, not final).

        A timed-out request is sent again only when its action is idempotent (a read):
        `retries` times (default 2 for idempotent actions, 0 otherwise).
        `on_feedback(Progress)`: asks for the action's progress, called for each progress inform.
        Cancelling the awaiting task cancels the action at the responder (a FIPA cancel)."""
        if retries is None:
            retries = 2 if content.idempotent else 0
        for attempt in range(retries + 1):
            try:
                return await self._request_once(to, content, timeout, performative, on_feedback)
            except RequestTimeout:
                if attempt == retries:
                    raise
                self.tracer.record(RecordKind.RETRY, agent=self.address, peer=to, action=content.action_name,
                                   attempt=attempt + 1)
        raise AssertionError("unreachable")

    async def _request_once(self, to: str, content: Action, timeout: float,
                            performative: Performative, on_feedback=None) -> Content:
        msg = make_message(to, content, performative=performative, feedback=on_feedback is not None)
        conv = msg.get_metadata(acl.CONVERSATION_ID)
        queue: asyncio.Queue = asyncio.Queue()
        self._pending[conv] = queue
        self._pending_peer[conv] = bare(to)
        self._outbox[conv] = msg
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        name = content.action_name
        try:
            await self.send(msg)
            if bare(to) not in self._heard_from and (self.settings.force_xmpp or self.local_agent(to) is None):
                self._first_contact(conv, msg)
            while True:
                remaining = deadline - loop.time()
                if remaining <= 0:
                    if not self.holds_requests_to(to):
                        raise asyncio.TimeoutError
                    deadline, remaining = loop.time() + timeout, timeout  # held (paused task): wait on
                try:
                    async with asyncio.timeout(remaining):  # no extra task per wait, unlike wait_for
                        answer = await queue.get()
                except asyncio.TimeoutError:
                    if self.holds_requests_to(to):
                        continue
                    raise
                if answer is None:
                    raise RequestFailed(f"{self.address} stopped while waiting for {name}",
                                        code=ErrorCode.STOPPED, peer=to, action=name)
                if isinstance(answer, Exception):  # fail_pending: the peer is known to be gone
                    raise answer
                perf = answer.get_metadata(acl.PERFORMATIVE)
                if perf == Performative.AGREE.value:
                    continue
                if perf == Performative.INFORM.value and is_feedback(answer):
                    self._feedback(on_feedback, answer, name)
                    continue
                if perf == Performative.INFORM.value:
                    try:
                        return validate(content.reply_model or Content, parse_json(answer.body))
                    except ContentError as e:
                        raise RequestFailed(f"{to} answered {name} with bad content: {e}",
                                            code=ErrorCode.BAD_REPLY, peer=to, action=name) from None
                reason = _reason_of(answer)
                err = {Performative.REFUSE.value: RequestRefused,
                       Performative.NOT_UNDERSTOOD.value: NotUnderstood}.get(perf, RequestFailed)
                raise err(reason.reason, code=reason.code, peer=to, action=name)
        except asyncio.TimeoutError:
            self.tracer.record(RecordKind.TIMEOUT, agent=self.address, peer=to, action=name,
                               conversation_id=conv, timeout_s=timeout)
            raise RequestTimeout(f"{to} did not answer {name} within {timeout:g}s",
                                 code=ErrorCode.TIMEOUT, peer=to, action=name) from None
        except asyncio.CancelledError:  # the requester gave up: the responder stops the action too
            self.submit(self.send(make_message(to, None, performative=Performative.CANCEL,
                                               ontology=content.ontology_name, action=name, conversation_id=conv)))
            raise
        finally:
            self._pending.pop(conv, None)
            self._pending_peer.pop(conv, None)
            self._outbox.pop(conv, None)

    @staticmethod
    def _feedback(on_feedback, answer: Message, name: str) -> None:
        if on_feedback is None:
            return
        try:
            on_feedback(validate(Progress, parse_json(answer.body)))
        except Exception:  # noqa: BLE001 - a bad callback or feedback must not end the request
            log.exception("feedback of %s not handled", name)

    def fail_pending(self, peer: str, error: Exception) -> int:
        """End every request waiting for an answer from `peer` with `error` (it is known to be
        gone: no use waiting for the timeout). Returns how many."""
        convs = [c for c, p in self._pending_peer.items() if p == bare(peer)]
        for conv in convs:
            self._pending[conv].put_nowait(error)
        return len(convs)

    async def notify(self, to: str, content: Content, *, ontology: str, action: str,
                     performative: Performative = Performative.INFORM) -> None:
        """One-way message (no answer expected)."""
        await self.send(make_message(to, content, performative=performative, ontology=ontology,
                                     action=action, protocol=acl.Protocol.NOTIFY.value))

    # -- behaviour activation (supervision moves by these) ----------------------------------
    def activate(self, name: str, behaviour, template=None) -> None:
        if name in self._named:
            return
        self._named[name] = behaviour
        self.add_behaviour(behaviour, template)
        self.tracer.record(RecordKind.BEHAVIOUR, event="activated", agent=self.address, behaviour=name)

    def deactivate(self, name: str) -> None:
        behaviour = self._named.pop(name, None)
        if behaviour is None:
            return
        if self.has_behaviour(behaviour):
            self.remove_behaviour(behaviour)
        self.tracer.record(RecordKind.BEHAVIOUR, event="deactivated", agent=self.address, behaviour=name)
        # requests already queued to it are re-routed, not lost
        queue = getattr(behaviour, "queue", None)
        while queue is not None and not queue.empty():
            msg = queue.get_nowait()
            self.submit(self._unhandled(msg, AclInfo.of(msg)))

    def remove_behaviour(self, behaviour) -> None:
        # idempotent: SPADE removes a finished one-shot behaviour itself, after we may have
        if self.has_behaviour(behaviour):
            super().remove_behaviour(behaviour)

    def active_behaviours(self) -> set[str]:
        return {n for n, b in self._named.items() if not b.is_killed()}

    def record_structure(self, event: str, **fields) -> None:
        self.tracer.record(RecordKind.STRUCTURE, event=event, agent=self.address, **fields)

    # -- tracing ----------------------------------------------------------------------------
    def _trace_message(self, direction: str, msg: Message, path: str, info: AclInfo | None = None) -> None:
        if not self.tracer.enabled:
            return
        info = info or AclInfo.of(msg)
        self.tracer.message(
            direction, self.address, bare(msg.sender), bare(msg.to), info.performative or "chat",
            info.conversation_id, info.ontology, info.action, info.reply_with, info.in_reply_to, path,
            len(msg.body or ""),
            # a RApp's report is its result: kept whole (up to a message's size limit), the rest capped
            cap(msg.body, REPORT_CAP if (info.ontology, info.action) == (C.ONTOLOGY, "report") else CONTENT_CAP),
            feedback=is_feedback(msg))  # a progress inform, not an answer
        if self.tracer.bodies is not None:  # a recording: the whole body too (agents/tracing.py)
            self.tracer.body(direction, self.address, bare(msg.sender), bare(msg.to), info.performative or "chat",
                             info.conversation_id, info.ontology, info.action, info.reply_with, info.in_reply_to,
                             msg.body or "", feedback=is_feedback(msg))


def _accepts(behaviour, msg: Message) -> bool:
    """Only behaviours that asked for messages get them: a template or their own match().

    (SPADE lets a behaviour without a template take every message into a queue it may never
    read; a request would then go unanswered.)"""
    if not behaviour.is_running or behaviour.is_killed():
        return False
    if behaviour.template is None and type(behaviour).match is _BASE_MATCH:
        return False
    return behaviour.match(msg)


_BASE_MATCH = CyclicBehaviour.match


def _reason_of(msg: Message) -> Reason:
    try:
        return Reason.model_validate(parse_json(msg.body))
    except Exception:  # noqa: BLE001 - a peer's malformed error still becomes an error
        return Reason(reason=(msg.body or "no reason given")[:500], code=ErrorCode.UNKNOWN)


__all__ = ["RappAgent", "CyclicBehaviour", "FSMBehaviour"]
