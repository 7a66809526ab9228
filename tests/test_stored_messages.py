"""A message to a user who is not online yet is stored and delivered when the user comes online,
even when its arrival and the user's initial presence reach the embedded server at once (as when a
restarted Core announces itself while its owner's command is already on the way).

pyjabber 0.4.5 handed both to a queue worker that took them in no fixed order: a message stored
after the recipient's "online" notice was handled waited for a next notice that never came
(xmpp_server/compat.py `_patch_session_routes`). The server is paused (SIGSTOP) while both
stanzas are sent, so that it reads them in the same turn of its loop.
"""
from __future__ import annotations

import asyncio
import os
import signal

from xmpp_server import EmbeddedServer
from xmpp_server.chat import ChatUser
from xmpp_server.probe import remove_account

TRIES = 8  # the old worker lost about one in two: all eight delivered is no luck


class LateUser(ChatUser):
    """Logs in without announcing itself (no initial presence) until told to."""

    def _on_session(self, _):
        if not self._session.done():
            self._session.set_result(True)


async def test_a_message_sent_as_its_recipient_comes_online_is_delivered():
    async with EmbeddedServer() as server:
        settings = server.settings()
        sender = ChatUser("sender", settings)
        await sender.start()
        try:
            for i in range(TRIES):
                late = LateUser(f"late{i}", settings)
                await late.start()
                os.kill(server.proc.pid, signal.SIGSTOP)
                try:
                    await sender.say(f"late{i}", f"hello {i}")
                    late.send_presence()
                    await asyncio.sleep(0.3)  # both stanzas wait in the paused server's sockets
                finally:
                    os.kill(server.proc.pid, signal.SIGCONT)
                try:
                    await late.wait_for(lambda t, i=i: t == f"hello {i}", timeout=5)
                finally:
                    await late.stop()
        finally:
            await sender.stop()


async def test_a_removed_accounts_stored_messages_go_with_it():
    """A message stored for an account that is then removed (a Dynamic Agent's, at its run's end)
    is not handed to a later account of the same name."""
    async with EmbeddedServer() as server:
        settings = server.settings()
        sender = ChatUser("sender", settings)
        await sender.start()
        old = LateUser("reused", settings)  # registers the account, never announces itself
        await old.start()
        await old.stop()
        again = None
        try:
            await sender.say("reused", "for the old account")
            await asyncio.sleep(0.5)  # stored
            await remove_account(settings.host, settings.port, settings.domain, user="reused",
                                 password=settings.password_for("reused"))
            again = ChatUser("reused", settings)  # registers anew and announces itself
            await again.start()
            await sender.say("reused", "for the new one")
            await again.wait_for(lambda t: t == "for the new one", timeout=5)
            assert again.texts() == ["for the new one"]
        finally:
            await sender.stop()
            if again is not None:
                await again.stop()
