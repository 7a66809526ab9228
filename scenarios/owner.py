"""The robot owner's client in scenarios: a plain XMPP chat client (xmpp_server/chat.py) that also
speaks the Core's task records (ontology/results.py) over the same connection.

    owner = OwnerClient("owner-nao1", settings); await owner.start()
    await owner.watch_tasks("core-nao1")            # FIPA subscribe: the Core tells its records
    await owner.say("core-nao1", "check the hazards")
    record = await owner.task_end(timeout=600)      # a TaskRecord: rapp, ok, reason, reports, ...

ACL messages are not chat: they never appear in `received` / `texts()` (the chat the owner reads).
"""
from __future__ import annotations

import asyncio
from collections.abc import Callable

from agents.messages import AclInfo, make_message
from agents.stanza import ACL_NS, message_xml, read_message
from ontology.acl import Performative
from ontology.common import Reason
from ontology.registry import ContentError, parse_json, validate
from ontology.results import ScheduleChanged, SubscribeTasks, TaskEnded, TaskRecord, TaskReported
from xmpp_server.chat import ChatUser

_ACL = "{%s}acl" % ACL_NS


class OwnerClient(ChatUser):
    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        self.reported: list[TaskReported] = []  # every report told, in order
        self.ended: list[TaskRecord] = []  # every command's end, in order
        self.schedules: list[ScheduleChanged] = []  # every change of the Core's schedules told, in order
        self.bad: list[str] = []  # ACL content that did not validate (kept, never fatal)
        self._answers: dict[str, asyncio.Future] = {}  # conversation -> the answer to our subscribe
        self._news = asyncio.Event()

    def _on_message(self, msg):
        if msg.xml.find(_ACL) is None:
            super()._on_message(msg)
            return
        acl = read_message(msg)
        info = AclInfo.of(acl)
        waiting = self._answers.pop(info.conversation_id, None)
        if waiting is not None and not waiting.done():
            waiting.set_result((info.performative, acl.body))
            return
        try:
            if info.action == TaskReported.action_name:
                self.reported.append(validate(TaskReported, parse_json(acl.body)))
            elif info.action == TaskEnded.action_name:
                self.ended.append(validate(TaskEnded, parse_json(acl.body)).record)
            elif info.action == ScheduleChanged.action_name:
                self.schedules.append(validate(ScheduleChanged, parse_json(acl.body)))
            else:
                return
        except ContentError as e:
            self.bad.append(str(e))
            return
        self._news.set()

    async def watch_tasks(self, core: str, timeout: float = 20.0) -> None:
        """Subscribe to the Core's task records (only its owner may); RuntimeError when refused."""
        msg = make_message(self.settings.jid(core), SubscribeTasks(), performative=Performative.SUBSCRIBE)
        msg.sender = str(self.boundjid)
        answer = asyncio.get_running_loop().create_future()
        self._answers[AclInfo.of(msg).conversation_id] = answer
        self.send_raw(message_xml(msg))
        performative, body = await asyncio.wait_for(answer, timeout)
        if performative != Performative.INFORM.value:
            try:
                why = Reason.model_validate(parse_json(body)).reason
            except Exception:  # noqa: BLE001 - a malformed refusal is still a refusal
                why = body or ""
            raise RuntimeError(f"{core} refused to tell its task records ({performative}): {why}")

    async def schedule_change(self, timeout: float, start: int = 0) -> ScheduleChanged:
        """The first change of the Core's schedules told from index `start` of `schedules` on."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while len(self.schedules) <= start:
            remaining = deadline - loop.time()
            if remaining <= 0:
                raise asyncio.TimeoutError(f"no schedule change within {timeout:g} s")
            self._news.clear()
            try:
                await asyncio.wait_for(self._news.wait(), remaining)
            except asyncio.TimeoutError:
                pass
        return self.schedules[start]

    async def task_end(self, timeout: float, start: int = 0,
                       accept: Callable[[TaskRecord], bool] = lambda r: True) -> TaskRecord:
        """The first accepted end of a command from index `start` of `ended` on; TimeoutError after `timeout` s."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        seen = start
        while True:
            for record in self.ended[seen:]:
                if accept(record):
                    return record
            seen = len(self.ended)
            remaining = deadline - loop.time()
            if remaining <= 0:
                raise asyncio.TimeoutError(f"no task end within {timeout:g} s")
            self._news.clear()
            try:
                await asyncio.wait_for(self._news.wait(), remaining)
            except asyncio.TimeoutError:
                pass
