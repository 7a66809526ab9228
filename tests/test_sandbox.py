"""Hostile RApps (issue: RApps are untrusted code). A real server, real processes: each attack of
tests/fixtures/hostile_app runs as a RApp on a robot and reports what it got; every attempt must
be refused, the refusal visible (in the trace), the robot safe and the Core back in supervision.
"""
from __future__ import annotations

import asyncio
import json
import os
import shutil
import socket
import sys
from pathlib import Path

import pytest
import yaml

from agents.sandbox import ENV_ALLOWED, MALLOC_ENV, available
from agents.tracing import read_trace
from robots import RobotAPI, World
from scenarios.system import RappSystem
from xmpp_server.probe import LoginError, probe_login

from .test_lifecycle import FIXTURE, structure, variant, wait_until

HOSTILE = Path(__file__).parent / "fixtures" / "hostile_app"
ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.skipif(not available(), reason="the RApp sandbox needs root (mount namespace, "
                                                        "uid of its own); CI runs as root")


def hostile(workdir: Path, attack: str, **params) -> Path:
    dest = workdir / f"hostile-{attack}"
    shutil.copytree(HOSTILE, dest)
    manifest = yaml.safe_load((dest / "manifest.yaml").read_text())
    manifest.update(name=f"hostile-{attack}".replace("_", "-"), keywords=["attack" + attack.replace("_", "")])
    manifest["params"].update(attack=attack, **params)
    (dest / "manifest.yaml").write_text(yaml.safe_dump(manifest))
    return dest


@pytest.fixture(scope="module")
async def system(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("sandbox")
    world = World.from_file("small", seed=4)
    async with RappSystem(workdir, trace_file=workdir / "trace.jsonl") as system:
        await system.publish(FIXTURE)
        await system.publish(variant(workdir, "cloud-linger", "cloudlinger", use_cloud=True,
                                     behaviour="linger", seconds=120))  # until test_g cancels it
        system.a = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")))
        system.b = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao", name="nao2")), robot_id="nao2")
        for h in (system.a, system.b):
            await wait_until(lambda h=h: h.core.token and h.core.listening, timeout=30)
        system.workdir = workdir
        yield system
    world.close()


def secrets_of(system) -> set[str]:
    """Every secret of the run: the agents' passwords, the owners' passwords, the Cores' tokens."""
    found = {p.read_text().strip() for p in (system.workdir / "credentials").glob("*.password")}
    found |= {h.core.password for h in (system.a, system.b)} | {h.core.token for h in (system.a, system.b)}
    assert len(found) >= 6 and all(found)
    return found


async def attack(system, name: str, handle=None, timeout: float = 60.0, **params) -> tuple[dict, str]:
    """Publish and run the hostile RApp for `name`; its report (dict) and the Core's final line."""
    handle = handle or system.a
    await system.publish(hostile(system.workdir, name, **params))
    await wait_until(lambda: handle.core.listening
                     and "user-listener" in handle.core.active_behaviours(), timeout=30)
    user, start = handle.user, len(handle.user.received)
    await user.say(handle.core.address, f"attack{name.replace('_', '')}")
    rapp = f"hostile-{name}".replace("_", "-")
    end = await user.wait_for(lambda t: t.startswith(f"{rapp} finished") or t.startswith(f"{rapp} ended"),
                              timeout=timeout, start=start)
    label = f"[{rapp}] "  # a RApp's words reach the owner labelled as its own
    reports = [t[len(label):] for t in user.texts()[start:] if t.startswith(label + "{")]
    return (json.loads(reports[-1]) if reports else {}), end


async def assert_safe_and_supervising(handle) -> None:
    """The robot does not move and the Core is back in supervision (within 2 s of the end)."""
    assert not handle.api.moving_forward()
    await wait_until(lambda: handle.core.listening and "user-listener" in handle.core.active_behaviours(),
                     timeout=2.0, what="supervision back")
    assert handle.core.dynamic is None


async def test_a_no_secret_in_environment_files_or_parent_proc(system):
    workdir = system.workdir
    paths = [str(p) for p in (workdir / "credentials").glob("*")] + [
        str(workdir / "trace.jsonl"), str(workdir / "xmpp.db"), str(workdir / "platform-data" / "users.db"),
        str(workdir / "store" / "store.db")]
    report, end = await attack(system, "secrets", paths=paths, globs=[f"{workdir}/**"])
    assert "finished" in end, end
    text = json.dumps(report)
    for secret in secrets_of(system):
        assert secret not in text, "a secret reached the RApp"
    assert set(report["env"]) <= set(ENV_ALLOWED) | set(MALLOC_ENV) | {
        "PYTHONPATH", "PYTHONDONTWRITEBYTECODE", "PYTHONNOUSERSITE", "HOME", "TMPDIR", "MPLCONFIGDIR",
        "RAPP_XMPP_HOST", "RAPP_XMPP_PORT", "RAPP_XMPP_DOMAIN", "RAPP_XMPP_AUTO_REGISTER",
        "RAPP_XMPP_VERIFY_TLS", "RAPP_FORCE_XMPP", "RAPP_START_TIMEOUT"}, sorted(report["env"])
    assert all(report["env"].get(k) == v for k, v in MALLOC_ENV.items())  # a frame's freed arrays unmapped
    assert all(v.startswith("ERR") for v in report["files"].values()), report["files"]
    assert report["uid"] != 0 and report["cwd"] == "/app"
    # the sandbox's /tmp is its own: at most the way to the project and Python when they live there
    ways = {Path(p).parts[2] for p in (str(ROOT), sys.prefix) if Path(p).parts[1:2] == ("tmp",)}
    assert report["listing"]["/proc"] == "ERR" and set(report["listing"]["/tmp"]) <= ways, report["listing"]
    await assert_safe_and_supervising(system.a)


async def test_b_cannot_log_in_as_any_agent(system):
    accounts = [system.a.core.name, system.b.core.name, "platform", "store", "publisher",
                system.a.user.boundjid.user]
    report, end = await attack(system, "login", accounts=[a.split("@")[0] for a in accounts],
                               paths=[str(p) for p in (system.workdir / "credentials").glob("*")])
    assert "finished" in end, end
    assert report["tried"] >= 2 and report["logged_in"] == []
    # its one connection is its agent's: every other was refused by its sandbox, and told
    assert any(r["what"] == "a second XMPP connection" for r in system.a.core.last_refusals), system.a.core.last_refusals
    assert "It was refused" in end, end
    await assert_safe_and_supervising(system.a)


async def test_c_its_identity_is_gone_after_the_run(system):
    report, end = await attack(system, "identity")
    assert "finished" in end, end
    jid, password = report["jid"], report["password"]
    s = system.settings
    await wait_until(lambda: any(r.get("account") == jid for r in structure(read_trace(s.trace_file))
                                 if r["event"] == "account-deleted"), timeout=10, what="account deleted")
    with pytest.raises(LoginError):
        await probe_login(s.host, s.port, s.domain, user=jid.split("@")[0], password=password,
                          register=False, timeout=5)
    await assert_safe_and_supervising(system.a)


async def test_d_another_users_token_is_refused(system):
    report, end = await attack(system, "other_user", stolen_token=system.b.core.token)
    assert "finished" in end, end
    assert "issued to another agent" in report["refused"]
    trace = read_trace(system.settings.trace_file)
    assert any(r["kind"] == "message" and r["performative"] == "refuse" and r["dir"] == "send"
               and r["agent"] == system.platform.address and "another agent" in r["content"] for r in trace)


async def test_e_cannot_write_outside_its_directory(system):
    targets = [str(system.workdir / "credentials" / "pwned"), "/tmp/rapp-pwned", str(ROOT / "agents" / "pwned.py"),
               str(system.a.core.workdir / "pwned"), "/etc/rapp-pwned", str(system.workdir / "pwned")]
    report, end = await attack(system, "write", targets=targets)
    assert "finished" in end, end
    writes = report["writes"]
    assert writes.pop("own.txt") == "written"
    writes.pop("/tmp/rapp-pwned")  # the sandbox's /tmp is its own (a tmpfs): nothing reaches the host's
    assert all(v.startswith("ERR") for v in writes.values()), writes
    assert not any(os.path.exists(t) for t in targets)


@pytest.mark.parametrize("name, check", [
    ("fork", lambda r: 0 < r["forked"] < 200 and "Resource temporarily unavailable" in r["error"]),
    ("memory", lambda r: r["allocated"] == 0 and r["error"] == "MemoryError"),
    ("sockets", lambda r: r["opened"] <= 1024 and "Too many open files" in r["error"]),
])
async def test_f_resource_limits_hold(system, name, check):
    report, end = await attack(system, name)
    assert check(report), (report, end)
    await assert_safe_and_supervising(system.a)


async def test_f_a_spinning_rapp_is_stopped_and_supervision_back_within_2s(system):
    report, end = await attack(system, "spin", timeout=30)
    assert "ended with a problem" in end and "heartbeat" in end, end
    events = structure(read_trace(system.settings.trace_file), system.a.core.address)
    ended = next(r for r in reversed(events) if r["event"] == "ended")
    resume = next(r for r in reversed(events) if r["event"] == "resume")
    assert 0 <= resume["t"] - ended["t"] <= 2.0, resume["t"] - ended["t"]
    await assert_safe_and_supervising(system.a)


async def test_g_cannot_stop_another_rapps_cloud_agent(system):
    b = system.b
    user, start = b.user, len(b.user.received)
    await user.say(b.core.address, "cloudlinger")
    await wait_until(lambda: any(c.rapp == "cloud-linger" for c in system.platform.clouds.values()), timeout=30)
    target = next(c.jid for c in system.platform.clouds.values() if c.rapp == "cloud-linger")
    report, end = await attack(system, "stop_cloud", target=target)
    assert report["stopped"] is False and "does not own" in report["refused"], report
    assert target in system.platform.clouds, "the other RApp's Cloud Agent still runs"
    events = structure(read_trace(system.settings.trace_file), system.platform.address)
    assert any(r["event"] == "refused" and r.get("cloud") == target for r in events)
    # the victim lingers until cancelled: a loaded machine took over 12 s to run the attack, and the
    # victim had ended by then ("no Cloud Agent")
    await user.say(b.core.address, "cancel")
    await user.wait_for(lambda t: t.startswith("cloud-linger") and "cancelled" in t, timeout=40, start=start)
    await wait_until(lambda: target not in system.platform.clouds, timeout=10, what="its Cloud Agent gone")


@pytest.mark.skipif(os.geteuid() != 0, reason="the sandbox's directory set-up changes owners: needs root")
def test_a_restart_does_not_follow_a_link_its_last_process_left(tmp_path):
    # a Cloud Agent restarts in its run directory, which its last process (the run's uid) could fill
    from agents.sandbox import Sandbox

    run, victim = tmp_path / "0001-app", tmp_path / "victim"
    run.mkdir()
    victim.mkdir()  # a directory: "made again" by mkdir(exist_ok=True), chowned through the link
    os.chown(victim, 4242, 4242)
    (run / "tmp").symlink_to(victim)
    (run / "dir-link").symlink_to(tmp_path)
    Sandbox(mode="root").prepare(run, 0x5AF0_0001)
    assert run.stat().st_uid == 0x5AF0_0001 and os.lstat(run / "tmp").st_uid == 0x5AF0_0001
    assert victim.stat().st_uid == 4242 and tmp_path.stat().st_uid == 0  # neither link was followed


# -- issue 41: what the sandbox's namespaces, control group, filter and relays hold -----------------
def _named(mark: str) -> list[int]:
    """Processes of the machine whose name is `mark` (the hostile chain names its processes so)."""
    out = []
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            try:
                if Path(entry.path, "comm").read_text().strip() == mark:
                    out.append(int(entry.name))
            except OSError:
                pass
    return out


async def test_h_nothing_outlives_the_run(system):
    mark = f"rapp-out-{os.getpid() % 10000}"
    report, end = await attack(system, "outlive", mark=mark)
    assert report.get("chain") and "finished" in end, (report, end)
    await wait_until(lambda: not _named(mark), timeout=3, what="the forking chain gone with its run")
    await asyncio.sleep(0.5)
    assert not _named(mark), "a process of the run outlived it"
    from agents.cgroups import support

    def empty_groups() -> list[Path]:  # a live process's (an idle warm worker's) group is not empty
        return [p for b in support().bases() if b.exists() for p in b.iterdir()
                if p.is_dir() and p.name.startswith(f"{os.getpid()}-") and not (p / "cgroup.procs").read_text().strip()]
    await wait_until(lambda: not empty_groups(), timeout=3, what="the run's control group removed")


async def test_i_only_the_xmpp_server_is_reachable(system):
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen()
    abstract = socket.socket(socket.AF_UNIX)
    name = f"rapp-test-{os.getpid()}"
    abstract.bind("\0" + name)
    abstract.listen()
    host_ips = sorted({a[4][0] for a in socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET)} - {"127.0.0.1"})
    try:
        tcp = [["127.0.0.1", listener.getsockname()[1]], *[[ip, system.settings.port] for ip in host_ips]]
        report, end = await attack(system, "network", tcp=tcp, abstract=[name])
    finally:
        listener.close()
        abstract.close()
    assert "finished" in end, end
    reached = report["reached"]
    assert all(v.startswith("ERR") for k, v in reached.items() if k != "interfaces"), reached
    assert reached["interfaces"] == ["lo"], reached  # and its own agent talked to the server all along


async def test_j_forbidden_system_calls_are_refused_and_told(system):
    report, end = await attack(system, "syscalls")
    assert report["syscalls"] and all(v == "Operation not permitted" for v in report["syscalls"].values()), report
    # told, not hidden: the owner's end message sums it up, the Core traced each refusal
    assert "finished. It was refused" in end and "system call ptrace (sandbox)" in end, end
    assert system.a.core.last_refusals and all(r["by"] == "sandbox" for r in system.a.core.last_refusals)
    refused = [r for r in structure(read_trace(system.settings.trace_file), system.a.core.address)
               if r["event"] == "refused" and r.get("by") == "sandbox"]
    assert {"system call bpf", "system call unshare", "system call mount"} <= {r["action"] for r in refused}


async def test_k_the_trace_cannot_be_erased_or_forged(system):
    core = system.a.core.address
    await system.a.user.watch_tasks(core)  # the owner's typed records of the run (ontology/results.py)
    ended = len(system.a.user.ended)
    report, end = await attack(system, "trace", core=core)
    assert report["has_writer"] and report["truncate"].startswith("ERR"), report  # a pipe: nothing to truncate
    records = read_trace(system.settings.trace_file)
    assert any(r.get("event") == "spawn" and r.get("agent") == core for r in records)  # the run's history is there
    forged = [r for r in records if r.get("claimed_agent") == core]
    assert len(forged) == 2 and all(r["origin"] == r["agent"] != core for r in forged), forged
    record = await system.a.user.task_end(10, start=ended)
    assert record.reports and not any("FORGED" in r.model_dump_json() for r in record.reports), record
    assert any(r.get("origin") and "not a trace record" in r.get("message", "") for r in records)


async def test_l_a_rapps_chat_is_labelled_as_its_own(system):
    report, end = await attack(system, "chat", owner=system.a.user.boundjid.bare)
    await asyncio.sleep(0.5)  # the direct message may come after the end
    lines = system.a.user.transcript(core=system.a.core.address)
    direct = [ln for ln in lines if ln.endswith(report["sent"]) and "(not your robot's Core)" in ln]
    relayed = [ln for ln in lines if ln.endswith(f"[hostile-chat] {report['sent']}")]
    assert direct and direct[-1].startswith("dyn-nao1-hostile-chat-"), lines[-6:]
    assert relayed and relayed[-1].startswith(system.a.core.name + ": "), lines[-6:]


async def test_m_one_cloud_agent_per_run_and_never_from_a_cloud_agent(system):
    report, end = await attack(system, "cloud_cloud")
    assert "second" in report, end
    assert "one per run" in report["second"], report
    assert "Store" in report["failed"] and report["first"], report  # a failed start left its try
    assert report["grandchild"]["ok"] is False and "only a Dynamic Agent" in report["grandchild"]["detail"], report
    assert "refused" in end and "start_cloud_agent" in end, end  # the Platform told the Core at the end
    await wait_until(lambda: not any(c.rapp == "hostile-cloud-cloud" for c in system.platform.clouds.values()),
                     timeout=10, what="its Cloud Agent gone with the run")


async def test_n_outputs_are_copied_without_following_links(system, tmp_path):
    from scenarios.run_rapp import _copy_outputs

    secret = system.workdir / "root-only"
    secret.write_text("root's secret")
    secret.chmod(0o600)
    links = {"creds": str(system.workdir / "credentials"), "secret": str(secret), "up": "../../../credentials"}
    report, end = await attack(system, "outputs", links=links, huge=70 * 1024**2)
    assert "finished" in end, end
    dest = tmp_path / "out"
    copied = _copy_outputs(read_trace(system.settings.trace_file), system.a.core.address, dest)
    assert copied == ["fine.txt"], copied
    assert sorted(p.name for p in dest.rglob("*")) == ["fine.txt"]


async def test_o_registrations_are_refused_to_a_rapp(system):
    report, end = await attack(system, "registry", store=system.store.address, robot="nao2")
    report.pop("attack")
    assert report.pop("get_state").startswith("answered"), report  # to its supervisor, the running RApp: yes
    assert all(v.startswith("refused") for v in report.values()), report
    assert system.platform.robots["nao2"].core_jid == system.b.core.address  # not overwritten


async def test_p_failed_logins_and_registrations_are_traced_by_the_server(system):
    s = system.settings
    with pytest.raises(LoginError):
        await probe_login(s.host, s.port, s.domain, user=system.a.core.name, password="guessed", register=False,
                          timeout=5)
    name = f"squatter{os.getpid()}"
    await probe_login(s.host, s.port, s.domain, user=name, password="x", register=True, timeout=5)
    events = [r for r in read_trace(s.trace_file) if str(r.get("agent", "")).startswith("xmpp-server@")]
    assert any(r["event"] == "login-failed" and r["account"] == system.a.core.name for r in events), events[-5:]
    assert any(r["event"] == "registered" and r["account"] == name for r in events), events[-5:]
