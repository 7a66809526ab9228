"""Generic runtime of Dynamic and Cloud Agents: load a RApp's entry point from its unpacked
package and run it as an agent with its own XMPP identity, in this process.

    python -m agents.runtime      (what the Core / Platform start, agents/process.py)

The spec (ontology/spawn.py SpawnSpec, with the run's one-time password) arrives on an inherited
pipe, read after the imports every run needs (a warm worker has done them before its hand-off);
where to connect comes from the allow-listed environment (agents/sandbox.py). The RApp's code is
imported only after the agent has logged in. A warm Cloud worker of the Platform (RAPP_WARM_LOGIN)
first reads its own account (WarmLogin, one line) and logs in while idle; its run's spec, naming
that account, follows at the hand-off.
"""
from __future__ import annotations

import asyncio
import faulthandler
import importlib
import os
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported where used: the sandbox's outer process (agents/confine.py) stays small
    from ontology.spawn import SpawnSpec, WarmLogin


def build_agent(spec: SpawnSpec, settings=None):
    """The Dynamic or Cloud Agent a spec describes (not started), logging in with the run's own
    account."""
    from ontology.manifest import load_manifest
    from xmpp_server.settings import XmppSettings

    settings = settings or XmppSettings.from_env()
    manifest = load_manifest(Path(spec.package_dir) / "manifest.yaml")
    if spec.kind == "dynamic":
        from .dynamic_agent import DynamicAgent
        return DynamicAgent(spec.name, manifest=manifest, package_dir=spec.package_dir, core=spec.core,
                            platform=spec.platform, token=spec.token, params=spec.params,
                            robot=spec.robot, settings=settings, password=spec.password)
    from .cloud_agent import CloudAgent
    return CloudAgent(spec.name, manifest=manifest, package_dir=spec.package_dir, owner=spec.owner,
                      token=spec.token, settings=settings, password=spec.password)


async def run_agent(agent, spec: SpawnSpec) -> int:
    if spec.kind == "cloud":
        return await agent.run_to_end(spec.platform)
    return await agent.run_to_end()


async def run_spec(spec: SpawnSpec | None, login: WarmLogin | None = None, pipe: tuple[int, bytes] = (-1, b"")) -> int:
    """Run `spec`'s agent to its end. A warm Cloud worker with a `login` logs in first, says it is
    ready, and only then reads its spec from `pipe` (descriptor, bytes already read; the hand-off):
    the run's Cloud Agent is the agent already logged in, its RApp code imported only now."""
    import signal

    loop = asyncio.get_running_loop()
    main_task = asyncio.current_task()
    # SIGTERM from the Core/Platform: log out cleanly (presence unavailable), then exit
    loop.add_signal_handler(signal.SIGTERM, main_task.cancel)
    agent = None
    try:
        if login is not None:
            agent, spec = await _logged_in_first(login, pipe)
            if agent is None:
                say_logged_out()
                return 0  # discarded idle: no run came
        else:
            agent = build_agent(spec)
        if spec.record:  # the run is recorded: the whole message bodies go to the relay too
            from .tracing import send_bodies_down_pipe
            send_bodies_down_pipe()
        if spec.kind == "cloud":
            from .crash_box import BOX_NAME, CrashBox
            agent.crash_box = CrashBox(Path.cwd() / BOX_NAME)  # in its run directory (cwd)
        code = await run_agent(agent, spec)
        say_logged_out()
        return code
    except asyncio.CancelledError:
        if agent is not None:
            await asyncio.wait_for(agent.stop(), 2.0)
        say_logged_out()
        return 143


async def _logged_in_first(login: WarmLogin, pipe: tuple[int, bytes]):
    """(the logged-in Cloud Agent, its run's spec), or (None, None) when the pool let it go idle."""
    from ontology.manifest import load_manifest
    from ontology.spawn import SpawnSpec
    from xmpp_server.settings import XmppSettings

    from .cloud_agent import CloudAgent

    agent = CloudAgent(login.name, settings=XmppSettings.from_env(), password=login.password)
    await agent.start(auto_register=True)  # its account is only reserved (agents/identity.py reserve)
    say_ready()
    data = await _read_to_end(*pipe)
    if not data.strip():
        await agent.stop()
        return None, None
    spec = SpawnSpec.model_validate_json(data)
    if spec.kind != "cloud" or spec.name != login.name:
        raise SystemExit(f"a warm Cloud worker logged in as {login.name} was handed {spec.kind} run {spec.name}")
    agent.begin(load_manifest(Path(spec.package_dir) / "manifest.yaml"), spec.package_dir, spec.owner, spec.token)
    return agent, spec


async def _read_to_end(fd: int, first: bytes) -> bytes:
    """The rest of the spec pipe, read by the loop (a thread blocked in read() would hold up the
    exit of a worker told to stop while idle); the descriptor is closed."""
    loop = asyncio.get_running_loop()
    chunks, done = [first], loop.create_future()

    def readable() -> None:
        try:
            chunk = os.read(fd, 65536)
        except BlockingIOError:
            return
        if chunk:
            chunks.append(chunk)
        elif not done.done():
            done.set_result(None)

    os.set_blocking(fd, False)
    loop.add_reader(fd, readable)
    try:
        await done
    finally:
        loop.remove_reader(fd)
        os.close(fd)
    return b"".join(chunks)


def read_login() -> tuple[WarmLogin, tuple[int, bytes]]:
    """A warm Cloud worker's account: the spec pipe's first line (the spec follows at the hand-off);
    with the descriptor and what was read past the line."""
    from ontology.spawn import WarmLogin

    fd, data = spec_fd(), b""
    while b"\n" not in data:
        chunk = os.read(fd, 65536)
        if not chunk:
            break
        data += chunk
    line, _, rest = data.partition(b"\n")
    return WarmLogin.model_validate_json(line), (fd, rest)


def spec_fd() -> int:
    """The pipe the parent left open (RAPP_SPEC_FD); the variable is forgotten, so RApp code does
    not find the descriptor's number there."""
    return int(os.environ.pop("RAPP_SPEC_FD"))


def read_spec() -> SpawnSpec:
    """The spec from the spec pipe, read once; the descriptor is closed."""
    from ontology.spawn import SpawnSpec

    with os.fdopen(spec_fd(), "rb") as f:
        return SpawnSpec.model_validate_json(f.read())


# imported later by every run, at first use: by SPADE (its loop policy, its agent page's template
# extension, built with every agent), slixmpp (at the first login: stream features, SASL, the
# plugins SPADE registers) and the RApps' requests (the robot API, the Platform's services)
LATER_IMPORTS = ("uvloop", "ctypes", "jinja2_time", "encodings.idna", "stringprep",
                 *(f"slixmpp.features.feature_{n}" for n in ("bind", "mechanisms", "preapproval", "rosterver",
                                                             "session", "starttls")),
                 "slixmpp.util.sasl", "slixmpp.util.stringprep_profiles",
                 *(f"slixmpp.plugins.xep_{n}" for n in ("0030", "0066", "0077", "0128", "0199")),
                 "ontology.robot", "ontology.services")


# what RApps' own modules commonly import (the hazard RApp's Cloud part): ~1 s of a warm Cloud
# Agent's 1.1 s start in bench/fleet.py. The Platform's warm workers import them ahead of time
# (PlatformAgent(warm_imports=...), ~60 MB more per idle worker, the SDK added by whoever builds the
# Platform: a layer above this one); a cold start does not (a RApp without them would pay), nor a
# Core's by default (a robot's memory; a bigger process also forks slower, which the sandbox's
# fork-limit test felt under load)
WARM_EXTRA_IMPORTS = ("numpy", "cv2", "scipy.optimize")


def preload(extra: tuple[str, ...] = ()) -> None:
    """Import what every run needs before the spec is read, and a warm worker's `extra` modules
    (agents/warm_pool.py does this ahead of time: a hand-off costs no interpreter start and no SPADE
    import)."""
    from xmpp_server.settings import XmppSettings  # noqa: F401
    from . import cloud_agent, dynamic_agent  # noqa: F401 - SPADE, slixmpp, the project's agents

    env = dict(os.environ)
    for name in LATER_IMPORTS + tuple(extra):
        try:
            importlib.import_module(name)
        except ImportError:  # a dependency's other version: imported at first use, as before
            pass
    if os.environ != env:  # cv2 adds LD_LIBRARY_PATH: the RApp gets the environment a cold start has
        os.environ.clear()
        os.environ.update(env)


def say_confined() -> None:
    """A warm worker tells its Core/Platform it has confined itself, and so set its own (idle) priority:
    a hand-off that raises it waits for this, lest the worker lower itself after (agents/process.py)."""
    fd = os.environ.get("RAPP_READY_FD")
    if fd is not None:
        try:
            os.write(int(fd), b"c")
        except BrokenPipeError:
            pass


def say_ready() -> None:
    """A warm worker tells its Core/Platform it has imported everything (RAPP_READY_FD), then
    forgets the descriptor."""
    fd = os.environ.pop("RAPP_READY_FD", None)
    if fd is not None:
        try:
            os.write(int(fd), b"1")
        except BrokenPipeError:
            pass  # handed its spec before it was ready: nobody listens any more
        os.close(int(fd))


_logged_out_fd: int | None = None  # RAPP_GONE_FD, taken out of the environment at start


def say_logged_out() -> None:
    """Tell the Core/Platform the agent has logged out, its output flushed: what is left is the
    process's exit, which they need not wait for (AgentProcess.end). Said once."""
    global _logged_out_fd
    fd, _logged_out_fd = _logged_out_fd, None
    if fd is None:
        return
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    try:
        os.write(fd, b"1")
    except OSError:
        pass
    os.close(fd)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv or "RAPP_SPEC_FD" not in os.environ:
        print("usage: python -m agents.runtime   (started by a Core or the Platform, which pass the "
              "spec on the descriptor named by RAPP_SPEC_FD)", file=sys.stderr)
        return 2
    from .sandbox import confine
    confine()  # first: the sandbox, as the Core or Platform asked (it never forks with a preexec_fn)
    from xmpp_server.compat import spade_without_its_server
    spade_without_its_server()  # before SPADE's import: an agent's process runs no server
    say_confined()
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    # a crash in native code (a Cloud Agent's OpenCV work, say) leaves its Python stack in stderr.log,
    # which the Core or Platform quotes in its record of the loss
    faulthandler.enable()
    global _logged_out_fd
    gone_fd = os.environ.pop("RAPP_GONE_FD", None)
    _logged_out_fd = int(gone_fd) if gone_fd else None
    trace_fd = os.environ.pop("RAPP_TRACE_FD", None)
    if trace_fd:
        from .tracing import inherit_trace_fd
        inherit_trace_fd(int(trace_fd))
    # a warm worker of a pool that names them (PlatformAgent/CoreAgent warm_imports): RApps' usual imports
    extra = os.environ.pop("RAPP_PRELOAD", "")
    preload(tuple(n for n in extra.split(",") if n) if "RAPP_READY_FD" in os.environ else ())
    if os.environ.pop("RAPP_WARM_LOGIN", None):  # a warm Cloud worker with an account: ready once logged in
        return asyncio.run(run_spec(None, *read_login()))
    say_ready()
    return asyncio.run(run_spec(read_spec()))


def exit_now(code: int) -> None:
    """End the process without the interpreter's teardown: with SPADE (and a warm worker's numpy,
    cv2, scipy) loaded it took 0.3-0.45 s after the agent had stopped, and the Core or Platform
    waits for the exit before it reports the RApp ended (bench/fleet.py: stop_cloud_agent). Exit
    handlers (pyjabber's temporary directory, logging) run and stdio is flushed first; trace lines
    are already written (one write each)."""
    import atexit

    atexit._run_exitfuncs()  # noqa: SLF001 - CPython's own exit handlers, run as at a normal exit
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


if __name__ == "__main__":
    exit_now(main())
