"""Hostile input: each gets a clear error, nothing is executed or stored, the agent keeps running."""
from __future__ import annotations

import asyncio
import io
import json
import tarfile

import pytest
from hypothesis import HealthCheck, given, settings as hsettings, strategies as st

from agents.base import MAX_BODY, RappAgent
from agents.errors import RequestRefused
from agents.messages import make_message
from agents.store_client import publish_package
from ontology import acl
from ontology import core as C
from ontology import platform as P
from ontology import store as S
from ontology.acl import Performative
from ontology.registry import actions
from robots import RobotAPI, World
from scenarios.system import RappSystem
from xmpp_server.compat import metadata_of

from .test_lifecycle import FIXTURE, run_command, variant, wait_until


@pytest.fixture(scope="module")
async def system(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("hostile")
    world = World.from_file("small", seed=6)
    async with RappSystem(workdir, trace_file=workdir / "trace.jsonl") as system:
        await system.publish(FIXTURE)
        system.handle = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")))
        await wait_until(lambda: system.handle.core.vocabulary and system.handle.core.listening)
        system.loop = asyncio.get_running_loop()
        system.attacker = RappAgent("attacker", system.settings)
        await system.attacker.start()
        await system.publisher.request(system.store.address, S.RegisterOwner(owner="mallory", password="pw"))
        yield system
        await system.attacker.stop()
    world.close()


def _tar(entries) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        for name, data, kind in entries:
            info = tarfile.TarInfo(name)
            if kind == "symlink":
                info.type, info.linkname = tarfile.SYMTYPE, "/etc/passwd"
            else:
                info.size = len(data)
            tar.addfile(info, io.BytesIO(data) if kind == "file" else None)
    return buf.getvalue()


MANIFEST = (FIXTURE / "manifest.yaml").read_bytes()
HOSTILE_PACKAGES = {
    "corrupt archive": (b"\x1f\x8b\x08\x00garbage" * 10, "corrupt"),
    "path traversal": (_tar([("manifest.yaml", MANIFEST, "file"), ("../evil.py", b"x", "file")]), ".."),
    "absolute path": (_tar([("manifest.yaml", MANIFEST, "file"), ("/tmp/evil.py", b"x", "file")]), "absolute"),
    "symlink": (_tar([("manifest.yaml", MANIFEST, "file"), ("link", b"", "symlink")]), "symlink"),
    "missing manifest": (_tar([("echo_app/task.py", b"x", "file")]), "manifest"),
    "invalid manifest": (_tar([("manifest.yaml", b"name: X\nversion: one\n", "file")]), "version"),
    "oversize": (b"\x1f\x8b" + b"\x00" * (17 * 1024 * 1024), "exceeds limit"),
}


@pytest.mark.parametrize("case", list(HOSTILE_PACKAGES))
async def test_store_refuses_hostile_package_and_keeps_running(system, case):
    data, expect = HOSTILE_PACKAGES[case]
    with pytest.raises(RequestRefused) as err:
        await publish_package(system.attacker, system.store.address, "mallory", "pw", data)
    assert expect in str(err.value).lower()
    listed = await system.attacker.request(system.store.address, S.ListPackages())
    assert [p.name for p in listed.packages] == ["echo-app"]  # nothing stored


async def test_package_for_another_robot_type_is_not_started(system, tmp_path):
    src = variant(tmp_path, "elektron-only", "elektrononly")
    m = src / "manifest.yaml"
    m.write_text(m.read_text().replace("robot_types:\n- nao\n- elektron", "robot_types:\n- elektron"))
    await system.publish(src)
    # the Core's vocabulary lists only its robot type's RApps, so ask for it by its name
    reply = await run_command(system, "please run elektrononly", "not understand")
    assert "elektrononly" in reply
    handle = system.handle
    handle.core.vocabulary["elektrononly"] = "elektron-only"  # as if it had slipped through
    reply = await run_command(system, "elektrononly", "could not get the application")
    assert "does not support a nao robot" in reply


def _raw(to, body, ontology, action, performative="request"):
    """A request-shaped message whose fields are whatever the attacker wants."""
    msg = make_message(to, None, performative="request", ontology=ontology, action=action)
    msg.body = body
    if performative:
        msg.set_metadata(acl.PERFORMATIVE, performative)
    else:
        metadata_of(msg).pop(acl.PERFORMATIVE)  # no performative at all: plain chat
    return msg


async def _answer(agent, msg, timeout=5.0):
    conv = msg.get_metadata(acl.CONVERSATION_ID)
    q: asyncio.Queue = asyncio.Queue()
    agent._pending[conv] = q
    try:
        await agent.send(msg)
        return await asyncio.wait_for(q.get(), timeout)
    finally:
        agent._pending.pop(conv, None)


def _targets(system):
    return {"core": (system.handle.core.address, "core", C.GetState()),
            "store": (system.store.address, "store", S.ListPackages()),
            "platform": (system.platform.address, "platform", P.ListServices())}


@pytest.mark.parametrize("target", ["core", "store", "platform"])
async def test_malformed_unknown_wrong_types_and_oversize(system, target):
    address, ontology, valid = _targets(system)[target]
    name = valid.action_name
    cases = [("{broken", name, "malformed JSON"), (json.dumps({"zzz": 1}), name, "Extra inputs"),
             ("{}", "self_destruct", "unknown action 'self_destruct'"),
             ("x" * (MAX_BODY + 10), name, "exceeds the limit")]
    if target == "store":
        cases.append((json.dumps({"keyword": 42}), "search", "keyword: Input should be a valid string"))
    for body, action, expect in cases:
        answer = await _answer(system.attacker, _raw(address, body, ontology, action))
        assert answer.get_metadata("performative") == "not-understood"
        assert expect in json.loads(answer.body)["reason"]
    await _still_answering(system, target)


async def _still_answering(system, target: str) -> None:
    """The agent answers a valid request (the Core refuses its state to anyone but its supervisor,
    owner and Platform: a refusal is an answer too)."""
    address, _, valid = _targets(system)[target]
    if target == "core":
        with pytest.raises(RequestRefused, match="may not read"):
            await system.attacker.request(address, valid, timeout=5)
    else:
        await system.attacker.request(address, valid, timeout=5)


async def test_forged_and_missing_tokens_are_refused(system):
    with pytest.raises(RequestRefused, match="unknown token"):
        await system.attacker.request(system.platform.address, P.Ping(token="forged"))
    with pytest.raises(RequestRefused, match="missing token"):
        await system.attacker.request(system.platform.address, P.Ping())


PERFORMATIVES = [p.value for p in Performative] + ["", "bogus"]
JSONISH = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
                       lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8), c, max_size=4),
                       max_leaves=12)


@hsettings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
@given(target=st.sampled_from(["core", "store", "platform"]),
       performative=st.sampled_from(PERFORMATIVES),
       ontology=st.sampled_from(["core", "store", "platform", "robot", "", "nonsense"]),
       action=st.sampled_from(sorted({a for o in ("core", "store", "platform", "robot") for a in actions(o)})
                              + ["", "rm -rf"]),
       body=st.one_of(JSONISH.map(json.dumps), st.text(max_size=200)))
def test_random_contents_never_break_an_agent(system, target, performative, ontology, action, body):
    address, valid_ontology, valid = _targets(system)[target]

    async def attack():
        await system.attacker.send(_raw(address, body, ontology, action, performative))
        # whatever happened, the agent still answers a valid request
        await _still_answering(system, target)

    system.loop.run_until_complete(attack())
