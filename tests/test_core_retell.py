"""A pause notice lost with the Core's connection is told again (agents/core_commands.py
`retell_task`, called by CoreAgent.on_reconnected): seen in a `--realism full` run, the Core's
"resumed" went out as a 5 s link outage began, the Dynamic Agent never had it and waited, paused,
for good (11 minutes, until the table was stopped)."""
from __future__ import annotations

from types import SimpleNamespace

from agents.core_commands import RobotCommands


class Host:
    robot_id = "nao1"

    def __init__(self):
        self.told: list[tuple[str, bool, str]] = []
        self.dynamic = SimpleNamespace(jid="dyn@localhost", ended=SimpleNamespace(is_set=lambda: False))

    async def notify(self, jid, note, ontology, action):
        self.told.append((jid, note.paused, note.reason))

    def record_structure(self, *a, **k):
        pass


async def _published(*a, **k):
    return None


async def test_the_core_tells_its_task_the_pause_state_again_twice():
    host = Host()
    commands = RobotCommands(host, _published)
    await commands.retell_task(again_after_s=0.01)
    assert host.told == [("dyn@localhost", False, "resumed")] * 2
    host.told.clear()
    commands.estop_reason = "obstacle ahead"
    await commands.retell_task(again_after_s=0.01)
    assert host.told == [("dyn@localhost", True, "obstacle ahead")] * 2
    host.dynamic = None  # no task running: nothing to tell
    host.told.clear()
    await commands.retell_task(again_after_s=0.01)
    assert host.told == []
