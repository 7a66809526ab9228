"""The Platform Agent's rights and load behaviour: tokens, per-user data, errors, overload;
services run through the agent over XMPP (they are unit-tested directly in tests/services)."""
from __future__ import annotations

import asyncio
import base64
import contextlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from agents.base import RappAgent
from agents.errors import NotUnderstood, RequestFailed, RequestRefused
from agents.platform_agent import PlatformAgent
from agents.services import SERVICES
from agents.services.images import encode_image
from agents.services.maps import encode_map
from ontology import platform as P
from ontology.services.common import Pose2D
from ontology.services.information import NewsExplore, WeatherCurrent
from ontology.services.navigation import PLAN_FOUND, ListMaps, PlanPath2D, UploadMap
from ontology.services.vision import FaceDetect, FindObjects, HumanDetect, LearnObject

PHOTOS = Path(__file__).resolve().parent / "data"  # see tests/data/README.md


@contextlib.asynccontextmanager
async def _platform(settings, unique, **kw):
    """A Platform Agent and a plain client agent, both stopped afterwards."""
    platform = PlatformAgent(unique("platform"), settings=settings, **kw)
    client = RappAgent(unique("client"), settings)
    await platform.start()
    try:
        await client.start()
        try:
            yield platform, client
        finally:
            await client.stop()
    finally:
        await platform.stop()


async def _token(client, platform, user, ttl=3600.0) -> str:
    try:
        await client.request(platform.address, P.RegisterUser(user=user, password="pw"))
    except RequestRefused:
        pass
    return (await client.request(platform.address, P.Login(user=user, password="pw", ttl_s=ttl))).token


async def test_expired_token_is_refused(settings, unique):
    async with _platform(settings, unique) as (platform, client):
        token = await _token(client, platform, "ann", ttl=0.3)
        assert (await client.request(platform.address, P.Ping(token=token))).user == "ann"
        await asyncio.sleep(0.4)
        with pytest.raises(RequestRefused, match="token expired"):
            await client.request(platform.address, P.Ping(token=token))
        with pytest.raises(RequestRefused, match="unknown user or wrong password"):
            await client.request(platform.address, P.Login(user="ann", password="wrong"))


def _map_upload(token: str, map_id: str) -> UploadMap:
    grid = np.full((20, 20), 254, np.uint8)
    grid[0, :] = 0
    png = base64.b64encode(cv2.imencode(".png", grid)[1].tobytes()).decode()
    yaml_text = ("image: map.png\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
                 "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return UploadMap(token=token, map_id=map_id, png_b64=png, yaml_text=yaml_text)


async def test_user_data_is_visible_only_to_its_owner(settings, unique):
    async with _platform(settings, unique) as (platform, client):
        ann, bob = await _token(client, platform, "ann"), await _token(client, platform, "bob")
        await client.request(platform.address, _map_upload(ann, "ann-flat"))
        ann_maps = {m.map_id for m in (await client.request(platform.address, ListMaps(token=ann))).maps}
        bob_maps = {m.map_id for m in (await client.request(platform.address, ListMaps(token=bob))).maps}
        assert "ann-flat" in ann_maps and "ann-flat" not in bob_maps


async def test_overload_is_answered_never_left_pending(settings, unique):
    async with _platform(settings, unique, max_pending=2) as (platform, client):
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


async def test_login_gives_a_token_and_calls_without_a_valid_one_are_refused(settings, unique):
    async with _platform(settings, unique) as (platform, client):
        with pytest.raises(RequestRefused, match="unknown user or wrong password"):
            await client.request(platform.address, P.Login(user="nobody", password="pw"))
        token = await _token(client, platform, "dan")
        assert len(token) >= 20 and (await client.request(platform.address, P.Ping(token=token))).user == "dan"
        with pytest.raises(RequestRefused, match="missing token") as no_token:
            await client.request(platform.address, WeatherCurrent(city="Warsaw"))
        assert no_token.value.code == "no-token"
        with pytest.raises(RequestRefused, match="unknown token") as forged:
            await client.request(platform.address, WeatherCurrent(token=token[::-1], city="Warsaw"))
        assert forged.value.code == "bad-token"


async def test_unknown_service_is_not_understood_and_service_errors_are_failures(settings, unique):
    without_news = {name: spec for name, spec in SERVICES.items() if name != "news_explore"}
    async with _platform(settings, unique, services=without_news) as (platform, client):
        token = await _token(client, platform, "eve")
        with pytest.raises(NotUnderstood, match="news_explore"):
            await client.request(platform.address, NewsExplore(token=token, keywords=["robots"]))
        with pytest.raises(RequestFailed, match="no weather data for city 'Atlantis'") as failed:
            await client.request(platform.address, WeatherCurrent(token=token, city="Atlantis"))
        assert failed.value.code == "unknown_city"
        assert (await client.request(platform.address, P.Ping(token=token))).user == "eve"  # still serving


RES = 0.05


def _room_upload(token: str, map_id: str) -> UploadMap:
    """A 3 m x 3 m empty room with walls around it."""
    blocked = np.zeros((60, 60), bool)
    blocked[0, :] = blocked[-1, :] = blocked[:, 0] = blocked[:, -1] = True
    png, yaml_text = encode_map(blocked, RES)
    return UploadMap(token=token, map_id=map_id, png_b64=base64.b64encode(png).decode(), yaml_text=yaml_text)


def _plan(token: str, map_id: str) -> PlanPath2D:
    return PlanPath2D(token=token, robot_type="nao", algorithm="astar", map_id=map_id,
                      start=Pose2D(x=0.7, y=0.7), goal=Pose2D(x=2.3, y=2.2))


async def test_plan_path_on_an_uploaded_map_is_private_to_its_user(settings, unique):
    async with _platform(settings, unique) as (platform, client):
        ann, bob = await _token(client, platform, "ann"), await _token(client, platform, "bob")
        info = await client.request(platform.address, _room_upload(ann, "room"))
        assert (info.width, info.height) == (60, 60)
        plan = await client.request(platform.address, _plan(ann, "room"), timeout=30)
        assert plan.plan_found == PLAN_FOUND and len(plan.path) >= 2 and 2.0 < plan.length_m < 3.0
        assert (await client.request(platform.address, _plan(bob, "room"), timeout=30)).plan_found != PLAN_FOUND


def _textured(seed: int) -> str:
    rng = np.random.default_rng(seed)
    img = np.full((160, 200), 255, np.uint8)
    for _ in range(80):
        x, y = (int(v) for v in rng.integers(0, 180, 2))
        cv2.rectangle(img, (x, y), (x + int(rng.integers(5, 30)), y + int(rng.integers(5, 30))),
                      int(rng.integers(0, 200)), -1)
    return encode_image(img)


async def test_learned_objects_belong_to_their_user(settings, unique):
    async with _platform(settings, unique) as (platform, client):
        ann, bob = await _token(client, platform, "ann"), await _token(client, platform, "bob")
        book = _textured(1)
        await client.request(platform.address, LearnObject(token=ann, name="book", image_b64=book), timeout=30)
        found = await client.request(platform.address, FindObjects(token=ann, image_b64=book), timeout=30)
        assert [o.name for o in found.objects] == ["book"]
        with pytest.raises(RequestFailed, match="no objects learned yet"):
            await client.request(platform.address, FindObjects(token=bob, image_b64=book), timeout=30)


async def test_hundred_concurrent_pings_and_plans_are_all_answered(settings, unique):
    async with _platform(settings, unique, max_pending=16) as (platform, client):
        token = await _token(client, platform, "fay")
        await client.request(platform.address, _room_upload(token, "room"))

        async def call(req):
            try:
                reply = await client.request(platform.address, req, timeout=60, retries=0)
                return "ping" if isinstance(reply, P.Pong) else f"plan {reply.plan_found}"
            except RequestRefused as e:
                assert e.code == "busy" and "platform busy" in e.reason
                return "busy"

        requests = [P.Ping(token=token) if i % 2 else _plan(token, "room") for i in range(100)]
        outcomes = await asyncio.gather(*(call(r) for r in requests))  # a timeout would raise
        assert outcomes.count("ping") == 50  # control calls are never refused as busy
        assert outcomes.count(f"plan {PLAN_FOUND}") >= 16
        assert outcomes.count(f"plan {PLAN_FOUND}") + outcomes.count("busy") == 50


async def test_face_and_human_detection_through_the_agent(settings, unique):
    async with _platform(settings, unique) as (platform, client):
        token = await _token(client, platform, "gil")
        photo = {n: base64.b64encode((PHOTOS / f"{n}.jpg").read_bytes()).decode() for n in ("astronaut", "cameraman")}
        faces = await client.request(platform.address, FaceDetect(token=token, image_b64=photo["astronaut"]))
        assert len(faces.boxes) == 1 and faces.boxes[0].x < 112 < faces.boxes[0].x + faces.boxes[0].width
        people = await client.request(platform.address, HumanDetect(token=token, image_b64=photo["cameraman"]))
        assert people.boxes and people.boxes[0].height > 150
        with pytest.raises(RequestFailed, match="could not be decoded"):
            await client.request(platform.address, FaceDetect(token=token, image_b64="bm90IGFuIGltYWdl"))
