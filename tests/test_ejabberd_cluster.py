"""RAPP across a two-node ejabberd cluster on loopback (xmpp_server/ejabberd.py): the Store and the
Platform log in to node 1, the robots' Cores and their owners to node 2, one XMPP domain. Every
message between them crosses the cluster (force_xmpp); the lifecycle runs across it, and when node
2 fails its clients reconnect through node 1 (settings.fallback) and serve the next command.

Opt-in by installation: skipped with a reason when ejabberd is missing (`apt-get install
ejabberd`), or when this machine cannot run clustered Erlang nodes at all.
"""
from __future__ import annotations

import asyncio
import contextlib

import pytest

from agents.tracing import read_trace
from robots import RobotAPI, World
from scenarios.system import RappSystem
from tests.test_lifecycle import check_lifecycle_over_the_wire, lifecycle_system, wait_until
from xmpp_server.ejabberd import EjabberdCluster, ejabberd_binary, erlang_distribution_problem
from xmpp_server.probe import probe_login
from xmpp_server.process import ServerStartError

pytestmark = [
    pytest.mark.ejabberd,
    pytest.mark.skipif(ejabberd_binary() is None,
                       reason="ejabberd is not installed (apt-get install ejabberd); "
                              "the cluster test needs ejabberdctl, erl and epmd"),
]
NODE_1, NODE_2 = 0, 1


async def start_cluster(workdir) -> EjabberdCluster:
    """Two clustered nodes; a skip only when the machine cannot run Erlang distribution at all
    (then it is not ejabberd's or our failure), else the start error fails the test."""
    cluster = EjabberdCluster(nodes=2, workdir=workdir)
    try:
        return await cluster.astart()
    except ServerStartError:
        problem = await asyncio.to_thread(erlang_distribution_problem)
        if problem:
            pytest.skip(f"Erlang nodes cannot be clustered on this machine: {problem}")
        raise


@contextlib.contextmanager
def robots_on(cluster: EjabberdCluster, index: int):
    """RappSystem.add_robot logs a robot's Core and owner in with system.settings (node 1, where
    the Store and Platform are); within this block they log in to node `index` instead, with the
    other nodes as fallback. Yields the robots added."""
    original, added = RappSystem.add_robot, []
    node = cluster.settings(index)

    async def add_robot(self, *args, **kw):
        shared = self.settings
        self.settings = shared.model_copy(update={"host": node.host, "port": node.port, "fallback": node.fallback})
        try:
            handle = await original(self, *args, **kw)
        finally:
            self.settings = shared
        added.append(handle)
        return handle

    RappSystem.add_robot = add_robot
    try:
        yield added
    finally:
        RappSystem.add_robot = original


def address(node) -> str:
    return f"{node.host}:{node.port}"


@pytest.fixture(scope="module")
async def cluster(tmp_path_factory):
    cluster = await start_cluster(tmp_path_factory.mktemp("ejabberd"))
    try:
        yield cluster
    finally:
        await asyncio.to_thread(cluster.close)


@pytest.fixture(scope="module")
async def system(cluster, tmp_path_factory):
    """Store and Platform on node 1; two nao robots (Core + owner) on node 2."""
    workdir = tmp_path_factory.mktemp("cluster-lifecycle")
    settings = cluster.settings(NODE_1, trace_file=workdir / "trace.jsonl", force_xmpp=True)
    world = World.from_file("small", seed=5)
    try:
        async with contextlib.AsyncExitStack() as stack:
            with robots_on(cluster, NODE_2) as robots:
                system = await stack.enter_async_context(lifecycle_system(workdir, settings))
                second = await system.add_robot("nao", api=RobotAPI(world.add_robot("nao")), robot_id="nao2")
            assert [r.core.settings.port for r in robots] == [cluster.nodes[NODE_2].port] * 2
            await wait_until(lambda: second.core.vocabulary and second.core.listening)
            yield system
    finally:
        world.close()


async def test_accounts_made_on_one_node_log_in_on_the_other(cluster):
    assert await asyncio.to_thread(cluster.nodes[NODE_1].cluster_nodes) == ["ejabberd1@localhost",
                                                                          "ejabberd2@localhost"]
    await asyncio.to_thread(cluster.nodes[NODE_1].register, "ctl-user", "ctl-pw")
    n2 = cluster.nodes[NODE_2]
    await probe_login(n2.host, n2.port, n2.domain, user="ctl-user", password="ctl-pw", register=False, timeout=5)


async def test_full_lifecycle_across_the_cluster(system, cluster):
    sessions = await asyncio.to_thread(cluster.nodes[NODE_1].sessions)
    assert sessions[system.store.address] == sessions[system.platform.address] == "ejabberd1@localhost"
    assert all(sessions[r.core.address] == sessions[r.user.boundjid.bare] == "ejabberd2@localhost"
               for r in system.robots), sessions

    # the Dynamic Agent (a child of the Core, on node 2) pinged the Platform (node 1); the Core
    # downloaded the RApp from the Store (node 1)
    trace, _ = await check_lifecycle_over_the_wire(system)
    assert any(r["sender"] == system.handle.core.address and r["receiver"] == system.store.address
               for r in trace if r["kind"] == "message" and r["dir"] == "send")


async def test_clients_of_a_failed_node_reconnect_through_the_other(system, cluster):
    node1, node2 = cluster.nodes[NODE_1], cluster.nodes[NODE_2]
    trace_file = system.settings.trace_file
    await asyncio.to_thread(node2.kill)  # SIGKILL: the node's connections are reset

    def reconnected(agent: str) -> bool:
        return any(r["kind"] == "agent" and r["event"] == "reconnected" and r["agent"] == agent
                   and r.get("server") == address(node1) for r in read_trace(trace_file))

    for robot in system.robots:
        await wait_until(lambda robot=robot: reconnected(robot.core.address), timeout=30,
                         what=f"{robot.core.address} reconnected through node 1", interval=0.2)
    # the Cores and their owners are all served by node 1 now
    accounts = {a for r in system.robots for a in (r.core.address, r.user.boundjid.bare)}
    await wait_for_sessions(node1, accounts, "ejabberd1@localhost")
    # each Core serves the next command: a new Dynamic Agent account is made and logged in
    # through node 1 (node 2 refuses), the RApp runs, the Core listens again
    for robot in system.robots:
        await wait_until(lambda robot=robot: robot.core.listening)
        start = len(robot.user.received)
        await robot.user.say(robot.core.address, "echo")
        await robot.user.wait_for(lambda t: "echo-app finished" in t, timeout=60, start=start)
    assert not node2.running()
    # node 2 started again (same spool) is a member of the cluster again and has caught up with
    # what changed while it was down
    await asyncio.to_thread(node1.register, "made-while-down", "pw")
    await node2.astart()
    assert await asyncio.to_thread(node1.cluster_nodes) == ["ejabberd1@localhost", "ejabberd2@localhost"]
    await probe_login(node2.host, node2.port, node2.domain, user="made-while-down", password="pw",
                      register=False, timeout=5)


async def wait_for_sessions(node, accounts: set[str], on: str, timeout: float = 15.0) -> None:
    """Until the cluster (asked through `node`) lists every account's session on node `on`."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        sessions = await asyncio.to_thread(node.sessions)
        if all(sessions.get(a) == on for a in accounts):
            return
        if loop.time() > deadline:
            raise TimeoutError(f"sessions not all on {on} within {timeout:g}s: {sessions}")
        await asyncio.sleep(0.3)


@pytest.mark.slow
async def test_two_robots_hazard_run_across_the_cluster(tmp_path):
    """scenarios/two_robots.py as is, on a cluster of its own: Store and Platform on node 1, the
    NAO's and the Elektron's Cores and owners on node 2; both robots' hazards correct."""
    from scenarios.two_robots import SPLIT, run_two_robots
    from tests.test_hazard_scenario import check_two_robots

    cluster = await start_cluster(tmp_path / "ejabberd")
    try:
        with robots_on(cluster, NODE_2) as robots:
            result = await run_two_robots(seed=1, house="small", out_dir=tmp_path / "run",
                                          settings=cluster.settings(NODE_1, force_xmpp=True))
    finally:
        await asyncio.to_thread(cluster.close)
    assert [r.robot_type for r in robots] == ["nao", "elektron"]
    assert all(r.core.settings.port == cluster.nodes[NODE_2].port for r in robots)
    check_two_robots(result, tmp_path / "run", SPLIT["small"])
    trace = read_trace(result["trace"])
    sent = [r for r in trace if r["kind"] == "message" and r["dir"] == "send"]
    assert sent and all(r["path"] == "xmpp" for r in sent)
    for r in robots:  # each Core downloaded the RApp from the Store on the other node
        assert any(m["sender"] == r.core.address and m["receiver"].startswith("store@") for m in sent)
