"""One sandboxed process tries what a RApp must not do, and this script says what it got.

    python tests/sandbox/battery.py OUT.json WORKDIR [SECRET_FILE]

run as root (the root sandbox) or as any other user (the rootless one): the same Sandbox() default
of agents/sandbox.py, the same AgentProcess, the same attempts (BATTERY below, inside the sandbox).
Around it, this script plays the Core: a listener standing for the XMPP server (reached through the
sandbox's forwarding), another loopback port and an abstract Unix socket (both must stay out of
reach), and after the run's end a look for any process of it left.
"""
import asyncio
import json
import os
import socket
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

BATTERY = r'''
import ctypes, json, os, socket, sys, time
from agents.sandbox import confine
confine()
a = json.loads(os.environ.get("BATTERY", "{}") or "{}")
libc = ctypes.CDLL(None, use_errno=True)
out = {"uid_is_root": os.getuid() == 0, "cwd": os.getcwd(), "proc": os.path.exists("/proc/1"),
       "root": sorted(os.listdir("/"))}
def err(call):
    try:
        call()
        return "done"
    except OSError as e:
        return "ERR"
out["read_secret"] = err(lambda: open(a["secret"]).read()) if a.get("secret") else "ERR"
out["writes"] = {p: err(lambda p=p: open(p, "w").write("x")) for p in ("/usr/pwned", "/etc/pwned", a["project"] + "/pwned")}
out["own_write"] = err(lambda: open("/app/own.txt", "w").write("x"))
calls = {"ptrace": (101, 0, 0, 0, 0), "mount": (165, b"none", b"/tmp", b"tmpfs", 0, 0), "unshare": (272, 0x10000000),
         "setns": (308, 0, 0), "bpf": (321, 0, 0, 0), "keyctl": (250, 0, 0), "perf_event_open": (298, 0, 0, -1, -1, 0),
         "kexec_load": (246, 0, 0, 0, 0), "finit_module": (313, 0, b"", 0), "clone_newuser": (56, 0x10000000 | 17, 0, 0, 0, 0)}
res = {}
for name, (nr, *args) in calls.items():
    r = libc.syscall(nr, *args)
    if r == 0 and name.startswith("clone"):
        os._exit(0)
    res[name] = "allowed" if r >= 0 else os.strerror(ctypes.get_errno())
out["syscalls"] = res
def reach(addr, family=socket.AF_INET):
    s = socket.socket(family)
    s.settimeout(2)
    try:
        s.connect(addr)
        return "connected"
    except OSError:
        return "ERR"
    finally:
        s.close()
out["other_port"] = reach(("127.0.0.1", a["other_port"]))
out["abstract"] = reach("\0" + a["abstract"], socket.AF_UNIX)
out["interfaces"] = sorted(n for _, n in socket.if_nameindex())
host, port = os.environ["RAPP_XMPP_HOST"], int(os.environ["RAPP_XMPP_PORT"])
first = socket.create_connection((host, port), timeout=3)
first.sendall(b"hello")
out["xmpp"] = first.recv(5).decode()
second = socket.create_connection((host, port), timeout=3)
second.settimeout(3)
try:
    out["second_xmpp"] = "answered" if second.recv(5) else "closed"
except OSError:
    out["second_xmpp"] = "closed"
pids = []
try:
    for _ in range(500):
        pid = os.fork()
        if pid == 0:
            time.sleep(30)
            os._exit(0)
        pids.append(pid)
    out["fork_limit"] = "none"
except OSError:
    out["fork_limit"] = "held" if len(pids) < 100 else f"late: {len(pids)}"
for pid in pids:
    os.kill(pid, 9)
    os.waitpid(pid, 0)
if os.fork() == 0:  # a chain that forks every 50 ms while its parents exit: it must die with the run
    os.setsid()
    libc.prctl(15, a["mark"].encode(), 0, 0, 0)
    while True:
        if os.fork():
            os._exit(0)
        time.sleep(0.05)
print(json.dumps(out), flush=True)
'''


def processes_named(mark: str) -> list[int]:
    found = []
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            try:
                if Path(entry.path, "comm").read_text().strip() == mark:
                    found.append(int(entry.name))
            except OSError:
                pass
    return found


async def main(out_file: str, workdir: str, secret: str | None) -> None:
    from agents.process import AgentProcess, Limits
    from agents.sandbox import Sandbox
    from ontology.spawn import SpawnSpec
    from xmpp_server.settings import XmppSettings

    server = socket.socket()  # stands for the XMPP server: echoes what it gets
    server.bind(("127.0.0.1", 0))
    server.listen()
    server.setblocking(False)
    other = socket.socket()
    other.bind(("127.0.0.1", 0))
    other.listen()
    abstract = socket.socket(socket.AF_UNIX)
    name = f"rapp-battery-{os.getpid()}"
    abstract.bind("\0" + name)
    abstract.listen()
    loop = asyncio.get_running_loop()

    async def echo():
        while True:
            conn, _ = await loop.sock_accept(server)
            loop.create_task(_echo(loop, conn))

    echoer = loop.create_task(echo())
    mark = f"battery-{os.getpid() % 100000}"
    work = Path(workdir)
    (work / "package").mkdir(parents=True, exist_ok=True)
    spec = SpawnSpec(kind="dynamic", name="dyn-battery", password="x", package_dir="", core="core@localhost",
                     platform="platform@localhost", token="t")
    sandbox = Sandbox()
    proc = AgentProcess("battery", spec, work, XmppSettings(host="127.0.0.1", port=server.getsockname()[1]),
                        limits=Limits(processes=40), sandbox=sandbox)
    proc.argv = [sys.executable, "-P", "-c", BATTERY]
    os.environ["BATTERY"] = json.dumps({"secret": secret, "project": str(ROOT), "other_port": other.getsockname()[1],
                                        "abstract": name, "mark": mark})
    env = sandbox.env
    sandbox.env = lambda settings, extra=None: {**env(settings, extra), "BATTERY": os.environ["BATTERY"]}
    await proc.start()
    code = await proc.wait()
    await asyncio.sleep(0.3)
    left = processes_named(mark)
    echoer.cancel()
    lines = (work / "stdout.log").read_text().strip().splitlines()
    result = json.loads(lines[-1]) if lines else {"stderr": (work / "stderr.log").read_text()[-2000:]}
    result.update(mode=sandbox.mode, exit_code=code, left_behind=len(left),
                  refused_told=sorted(r["what"] for r in proc.refusals))
    for pid in left:
        os.kill(pid, 9)
    Path(out_file).write_text(json.dumps(result))


async def _echo(loop, conn) -> None:
    try:
        while data := await loop.sock_recv(conn, 4096):
            await loop.sock_sendall(conn, data)
    except OSError:
        pass
    conn.close()


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else None))
