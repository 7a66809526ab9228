"""A sandboxed process sees what is bound into its root even when the source lies under /tmp, where
the sandbox builds that root on a tmpfs (agents/confine.py _build_root): a checkout or a virtualenv
under /tmp once made every RApp fail at start ("bind /tmp/.../.venv: No such file or directory")."""
from __future__ import annotations

import asyncio
import socket
import sys

import pytest

from agents.sandbox import probe

pytestmark = pytest.mark.skipif(probe().mode not in ("root", "user"), reason="no kernel sandbox on this machine")

READ_BOUND = r'''
from agents.sandbox import confine
confine()
print(open("/data/note.txt").read(), flush=True)
'''


async def test_a_bind_whose_source_is_under_tmp_is_seen_inside(tmp_path):
    from agents.process import AgentProcess, Limits
    from agents.sandbox import Sandbox
    from ontology.spawn import SpawnSpec
    from xmpp_server.settings import XmppSettings

    if not str(tmp_path).startswith("/tmp/"):
        pytest.skip(f"the case needs a source under /tmp; pytest's base directory is {tmp_path.parent}")
    data = tmp_path / "data"
    data.mkdir()
    (data / "note.txt").write_text("seen from inside")
    listener = socket.socket()  # stands for the XMPP server the sandbox forwards to
    listener.bind(("127.0.0.1", 0))
    listener.listen()
    work = tmp_path / "work"
    (work / "package").mkdir(parents=True)
    spec = SpawnSpec(kind="dynamic", name="dyn-binds", password="x", package_dir="", core="core@localhost",
                     platform="platform@localhost", token="t")
    sandbox = Sandbox(extra_binds=((str(data), "/data", False),))
    proc = AgentProcess("binds", spec, work, XmppSettings(host="127.0.0.1", port=listener.getsockname()[1]),
                        limits=Limits(processes=10), sandbox=sandbox)
    proc.argv = [sys.executable, "-P", "-c", READ_BOUND]
    try:
        await proc.start()
        code = await asyncio.wait_for(proc.wait(), 60)
    finally:
        listener.close()
    out, err = (work / "stdout.log").read_text(), (work / "stderr.log").read_text()
    assert code == 0 and "seen from inside" in out, err[-2000:]
