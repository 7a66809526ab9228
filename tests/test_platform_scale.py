"""Several Platform agents serving one domain (agents/platform_directory.py): a replica registers
with its primary, verifies tokens there (a revocation reaches it at once, and within TOKEN_CACHE_S
in any case), serves only the stateless services, and clients spread their calls by load."""
from __future__ import annotations

import asyncio
import contextlib

import cv2
import numpy as np
import pytest

from agents import platform_directory as D
from agents.base import RappAgent
from agents.errors import RequestRefused
from agents.platform_agent import PlatformAgent
from agents.services.images import encode_image
from ontology import platform as P
from ontology.services.common import Pose2D
from ontology.services.navigation import PlanPath2D
from rapps.sdk import PlatformProxy
from scenarios.system import wait_until


@contextlib.asynccontextmanager
async def _domain(settings, unique):
    """A primary, one replica (one worker process each) and a client with a token of the primary."""
    primary_name, replica_name = unique("platform"), unique("platform-r")
    primary = PlatformAgent(primary_name, settings=settings, service_workers=1, replicas=[replica_name])
    replica = PlatformAgent(replica_name, settings=settings, service_workers=1, primary=primary_name)
    client = RappAgent(unique("client"), settings)
    await primary.start()
    try:
        await replica.start()
        try:
            await client.start()
            try:
                await wait_until(lambda: primary.platforms.live(), 10, "replica registered")
                await client.request(primary.address, P.RegisterUser(user="ann", password="pw"))
                token = (await client.request(primary.address, P.Login(user="ann", password="pw"))).token
                yield primary, replica, client, token
            finally:
                await client.stop()
        finally:
            await replica.stop()
    finally:
        await primary.stop()


def _image(seed: int) -> str:
    rng = np.random.default_rng(seed)
    img = np.full((240, 320), 255, np.uint8)
    for _ in range(40):
        x, y = (int(v) for v in rng.integers(0, 300, 2))
        cv2.rectangle(img, (x, y), (x + 20, y + 15), int(rng.integers(0, 200)), -1)
    return encode_image(img)


async def test_two_platform_agents_serve_one_domain_and_calls_spread_by_load(settings, unique):
    async with _domain(settings, unique) as (primary, replica, client, token):
        listed = (await client.request(primary.address, D.ListPlatforms(token=token))).platforms
        assert [(e.jid, e.primary) for e in listed] == [(primary.address, True), (replica.address, False)]
        assert "hazard_detection_door_check" in listed[1].services and "path_planning_plan_path_2d" not in listed[1].services
        client.platform_chooser = D.PlatformChooser(client, primary.address, token)
        proxy = PlatformProxy(client, primary.address, token)  # as a RApp's task calls the Platform
        before = (primary.served, replica.served)
        replies = await asyncio.gather(*(proxy.hazard_detection_door_check(image_b64=_image(i), _timeout=60)
                                         for i in range(8)))
        assert all(0 <= r.door_angle <= 90 for r in replies)
        by_primary, by_replica = primary.served - before[0], replica.served - before[1]
        assert by_primary + by_replica == 8 and by_primary >= 2 and by_replica >= 2, (by_primary, by_replica)
        # stateful services stay with the primary, whatever the client does
        with pytest.raises(RequestRefused, match=f"served by the primary Platform {primary.address}") as e:
            await client.request(replica.address, PlanPath2D(token=token, robot_type="nao", map_id="m",
                                                             start=Pose2D(x=0, y=0), goal=Pose2D(x=1, y=1)))
        assert e.value.code == "not-serving"


def test_the_choice_goes_to_the_less_loaded_agent_per_worker():
    import random

    chooser = D.PlatformChooser(None, "p@x", "t", rng=random.Random(1))
    busy = D.PlatformEntry(jid="p@x", services=[], capacity=2, outstanding=6, primary=True)
    idle = D.PlatformEntry(jid="r@x", services=["qr_detection"], capacity=1, outstanding=1)
    assert {chooser.choose([busy, idle]) for _ in range(20)} == {"r@x"}  # 3 per worker against 1
    with chooser.track("r@x"), chooser.track("r@x"), chooser.track("r@x"):  # this client's own calls count
        assert {chooser.choose([busy, idle]) for _ in range(20)} == {"p@x"}


async def test_a_token_revoked_on_the_primary_is_refused_by_a_replica(settings, unique):
    async with _domain(settings, unique) as (primary, replica, client, token):
        assert (await client.request(replica.address, P.Ping(token=token))).user == "ann"
        await primary.revoke_token(token)  # told to the live replicas at once
        with pytest.raises(RequestRefused, match="unknown token"):
            await client.request(replica.address, P.Ping(token=token))
        # a notice lost on the way: the replica's cache still trusts it, for TOKEN_CACHE_S at most
        other = (await client.request(primary.address, P.Login(user="ann", password="pw"))).token
        assert (await client.request(replica.address, P.Ping(token=other))).user == "ann"
        primary._tokens.pop(other, None)
        assert await asyncio.to_thread(primary.directory.revoke, other)
        await asyncio.sleep(D.TOKEN_CACHE_S + 0.1)
        with pytest.raises(RequestRefused, match="unknown token"):
            await client.request(replica.address, P.Ping(token=other))


async def test_only_named_replicas_register_and_look_tokens_up(settings, unique):
    async with _domain(settings, unique) as (primary, replica, client, token):
        with pytest.raises(RequestRefused, match="is not a replica") as e:
            await client.request(primary.address, D.PlatformReport(services=["qr_detection"], capacity=8))
        assert e.value.code == "forbidden"
        with pytest.raises(RequestRefused, match="only this Platform's replicas"):
            await client.request(primary.address, D.LookupToken(token=token))
        assert [r.jid for r in primary.platforms.live()] == [replica.address]
