"""The Platform Agent's rights and load behaviour: token expiry, per-user data, overload."""
from __future__ import annotations

import asyncio
import base64

import cv2
import numpy as np
import pytest

from agents.base import RappAgent
from agents.errors import RequestFailed, RequestRefused
from agents.platform_agent import PlatformAgent
from ontology import platform as P
from ontology.services.information import WeatherCurrent
from ontology.services.navigation import ListMaps, UploadMap


async def _platform(settings, unique, **kw):
    platform = PlatformAgent(unique("platform"), settings=settings, **kw)
    client = RappAgent(unique("client"), settings)
    await platform.start()
    await client.start()
    return platform, client


async def _token(client, platform, user, ttl=3600.0) -> str:
    try:
        await client.request(platform.address, P.RegisterUser(user=user, password="pw"))
    except RequestRefused:
        pass
    return (await client.request(platform.address, P.Login(user=user, password="pw", ttl_s=ttl))).token


async def test_expired_token_is_refused(settings, unique):
    platform, client = await _platform(settings, unique)
    try:
        token = await _token(client, platform, "ann", ttl=0.3)
        assert (await client.request(platform.address, P.Ping(token=token))).user == "ann"
        await asyncio.sleep(0.4)
        with pytest.raises(RequestRefused, match="token expired"):
            await client.request(platform.address, P.Ping(token=token))
        with pytest.raises(RequestRefused, match="unknown user or wrong password"):
            await client.request(platform.address, P.Login(user="ann", password="wrong"))
    finally:
        await client.stop()
        await platform.stop()


def _map_upload(token: str, map_id: str) -> UploadMap:
    grid = np.full((20, 20), 254, np.uint8)
    grid[0, :] = 0
    png = base64.b64encode(cv2.imencode(".png", grid)[1].tobytes()).decode()
    yaml_text = ("image: map.png\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
                 "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return UploadMap(token=token, map_id=map_id, png_b64=png, yaml_text=yaml_text)


async def test_user_data_is_visible_only_to_its_owner(settings, unique):
    platform, client = await _platform(settings, unique)
    try:
        ann, bob = await _token(client, platform, "ann"), await _token(client, platform, "bob")
        await client.request(platform.address, _map_upload(ann, "ann-flat"))
        ann_maps = {m.map_id for m in (await client.request(platform.address, ListMaps(token=ann))).maps}
        bob_maps = {m.map_id for m in (await client.request(platform.address, ListMaps(token=bob))).maps}
        assert "ann-flat" in ann_maps and "ann-flat" not in bob_maps
    finally:
        await client.stop()
        await platform.stop()


async def test_overload_is_answered_never_left_pending(settings, unique):
    platform, client = await _platform(settings, unique, max_pending=2)
    try:
        token = await _token(client, platform, "cat")

        async def call():
            try:
                await client.request(platform.address, WeatherCurrent(token=token, city="Warsaw"), timeout=20)
                return "served"
            except RequestRefused as e:
                assert "platform busy" in e.reason
                return "busy"

        outcomes = await asyncio.gather(*(call() for _ in range(60)))  # a timeout would raise
        assert outcomes.count("served") >= 2 and outcomes.count("busy") >= 1
        assert (await client.request(platform.address, WeatherCurrent(token=token, city="Warsaw"))).city == "Warsaw"
        with pytest.raises(RequestFailed, match="Atlantis"):
            await client.request(platform.address, WeatherCurrent(token=token, city="Atlantis"))
    finally:
        await client.stop()
        await platform.stop()
