"""FIPA-Request responder: turns async handlers `(request model, ctx) -> reply model` into a behaviour.

    responder = Responder("robot", {"say": handle_say}, agree=False)
    agent.activate("command-server", responder, responder.make_template())

For each request: the content is validated against the registered model (malformed JSON, unknown
action or invalid fields -> not-understood naming the problem); `check` may refuse (supervision,
tokens); optionally `agree` is sent first; then the handler's reply goes back as inform. A handler
raising Refusal answers refuse, Failure or any other exception answers failure with the reason.
The behaviour survives every bad input.
"""
from __future__ import annotations

import asyncio
import logging
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Awaitable, Callable

from spade.behaviour import CyclicBehaviour
from spade.message import Message
from spade.template import Template

from ontology import acl
from ontology.acl import Performative
from ontology.common import Reason
from ontology.registry import Action, Content, ContentError, Progress, decode_request
from ontology.errors import ErrorCode
from ontology.trace import RecordKind

from .errors import Failure, Refusal
from .messages import AclInfo, bare, copy_message, is_feedback, reply_to

log = logging.getLogger("rapp.responder")
KEEP_ANSWERS = 4096  # conversations whose final answer a responder keeps for a resent request
KEEP_ANSWER_S = 300.0


@dataclass
class RequestContext:
    sender: str  # bare JID of the requester
    info: AclInfo
    message: Message
    user: str = ""  # set by a check that authenticates the request (Platform tokens)
    token: Any = None  # what that check knows of the token (agents.platform_users.TokenInfo)
    agent: Any = None  # the serving agent (sends the feedback)

    @property
    def wants_feedback(self) -> bool:
        return is_feedback(self.message)

    async def feedback(self, progress: Progress) -> None:
        """A progress inform to the requester, when it asked for feedback (else nothing is sent)."""
        if self.wants_feedback and self.agent is not None:
            await self.agent.send(reply_to(self.message, progress, Performative.INFORM, feedback=True))


Handler = Callable[[Action, RequestContext], Awaitable[Content | None]]
Check = Callable[[Action, RequestContext], Awaitable[None] | None]


class Responder(CyclicBehaviour):
    def __init__(self, ontology: str, handlers: dict[str, Handler], *, agree: bool = False,
                 concurrent: bool = True, check: Check | None = None,
                 performative: Performative = Performative.REQUEST):
        super().__init__()
        self.ontology, self.performative = ontology, performative
        self.handlers = dict(handlers)
        self.agree = agree
        self.concurrent = concurrent
        self.check = check
        self._tasks: set[asyncio.Task] = set()
        self._order = asyncio.Lock()
        # (sender, conversation) -> its final answer (None while it runs): a request sent again
        # after a reconnect is answered from here, never executed twice
        self._answers: OrderedDict[tuple[str, str], Message | None] = OrderedDict()
        self._answered_at: dict[tuple[str, str], float] = {}
        self._running: dict[tuple[str, str], asyncio.Task] = {}  # what a cancel can stop

    def make_template(self) -> Template:
        # constructor metadata: assigning template.metadata later matches everything (spade 4.1.4)
        return Template(metadata={"ontology": self.ontology, "performative": self.performative.value})

    async def run(self) -> None:
        msg = await self.receive(timeout=0.5)  # only messages queued before take_now existed
        if msg is not None:
            self.take_now(msg)

    def match(self, msg: Message) -> bool:
        """The template's requests, and a cancel of one in this ontology."""
        if msg.get_metadata(acl.PERFORMATIVE) == Performative.CANCEL.value:
            return msg.get_metadata(acl.ONTOLOGY) == self.ontology
        return super().match(msg)

    def take_now(self, msg: Message) -> asyncio.Future:
        """Called by RappAgent's router: serve at once, without SPADE's queue hop."""
        key = (bare(msg.sender), msg.get_metadata(acl.CONVERSATION_ID) or "")
        if msg.get_metadata(acl.PERFORMATIVE) == Performative.CANCEL.value:
            return self._cancel(key)
        if key[1] and key in self._answers:
            return self._repeat(key, msg)
        if key[1]:
            self._answers[key] = None
            self._expire_answers()
        if self.concurrent:
            task = asyncio.create_task(self.serve(msg))
        else:
            task = asyncio.create_task(self._serve_in_order(msg))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        if key[1]:
            self._running[key] = task
            task.add_done_callback(lambda _t, key=key: self._running.pop(key, None))
        return task

    def _cancel(self, key) -> asyncio.Future:
        """The requester cancels its running request: the handler is cancelled and the request
        ends with failure(cancelled). A cancel of nothing running is ignored (it crossed the answer)."""
        task = self._running.get(key)
        if task is not None:
            task.cancel()
        return _done()

    async def _serve_in_order(self, msg: Message) -> None:
        async with self._order:
            await self.serve(msg)

    async def serve(self, msg: Message) -> None:
        info = AclInfo.of(msg)
        ctx = RequestContext(sender=bare(msg.sender), info=info, message=msg, agent=self.agent)
        try:
            request = decode_request(info.ontology, info.action, msg.body)
            handler = self.handlers.get(info.action)
            if handler is None:
                raise ContentError(f"action {info.action!r} is not served by {self.agent.address}")
        except ContentError as e:
            await self._answer(msg, Performative.NOT_UNDERSTOOD, Reason(reason=str(e), code=ErrorCode.NOT_UNDERSTOOD))
            return
        try:
            if self.check is not None:
                res = self.check(request, ctx)
                if asyncio.iscoroutine(res):
                    await res
            if self.agree or ctx.wants_feedback:  # an action with feedback: request -> agree -> progress
                await self._answer(msg, Performative.AGREE, None)
            result = await handler(request, ctx)
        except Refusal as e:
            note = getattr(self.agent, "note_refusal", None)  # told, not hidden (Core, Platform, Store)
            if note is not None:
                note(ctx.sender, info.action, e)
            await self._answer(msg, Performative.REFUSE, Reason(reason=e.reason, code=e.code))
            return
        except Failure as e:
            await self._answer(msg, Performative.FAILURE, Reason(reason=e.reason, code=e.code))
            return
        except asyncio.CancelledError:
            await self._answer(msg, Performative.FAILURE, Reason(reason="cancelled", code=ErrorCode.CANCELLED))
            raise
        except Exception as e:  # noqa: BLE001 - any handler bug becomes a failure, the agent lives on
            code = getattr(e, "code", ErrorCode.ERROR)
            if hasattr(e, "code"):  # a typed domain error (robot, service, store): no traceback
                log.info("%s failed: %s", info.action, e)
            else:
                log.exception("handler for %s failed", info.action)
            await self._answer(msg, Performative.FAILURE,
                               Reason(reason=f"{type(e).__name__}: {e}", code=str(code)))
            return
        await self._answer(msg, Performative.INFORM, result)

    def _repeat(self, key, msg: Message) -> asyncio.Future:
        answer = self._answers[key]
        self.agent.tracer.record(RecordKind.DUPLICATE, agent=self.agent.address, sender=key[0], conversation_id=key[1],
                                 answered=answer is not None)
        if answer is None:  # still running: its answer goes out when it is done
            return _done()
        task = asyncio.create_task(self.agent.send(copy_message(answer)))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    def _expire_answers(self) -> None:
        """Answers are kept KEEP_ANSWER_S after they went out (a requester resends only after a
        reconnect, well within it), and never more than KEEP_ANSWERS conversations."""
        now = time.monotonic()
        while self._answers:
            key = next(iter(self._answers))
            done_at = self._answered_at.get(key)
            if len(self._answers) <= KEEP_ANSWERS and (done_at is None or now - done_at < KEEP_ANSWER_S):
                break
            self._answers.pop(key)
            self._answered_at.pop(key, None)

    async def _answer(self, msg: Message, performative: Performative, content: Content | None) -> None:
        reply = reply_to(msg, content, performative)
        key = (bare(msg.sender), msg.get_metadata(acl.CONVERSATION_ID) or "")
        if performative != Performative.AGREE and key in self._answers:
            self._answers[key] = reply
            self._answered_at[key] = time.monotonic()
        await self.agent.send(reply)

    async def on_end(self) -> None:
        for t in list(self._tasks):
            t.cancel()


def _done() -> asyncio.Future:
    """A future already done: what take_now returns when nothing more is to run."""
    done = asyncio.get_running_loop().create_future()
    done.set_result(None)
    return done
