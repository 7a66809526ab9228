"""The Platform's process pool for CPU-bound services (agents/services/pool.py), through the agent:
the services really run in other processes, a map crosses to a worker once, and a worker killed
during a call fails that call with a clear reason and is replaced."""
from __future__ import annotations

import asyncio
import base64
import contextlib
import os
import signal

import cv2
import numpy as np
import pytest

from agents.errors import RequestFailed
from agents.services.images import encode_image
from agents.services.maps import encode_map
from ontology.services.common import Pose2D
from ontology.services.hazard import DoorCheck, LightCheck
from ontology.services.information import WeatherCurrent
from ontology.services.navigation import PLAN_FOUND, PLAN_NOT_FOUND, PlanPath2D, UploadMap
from ontology.services.vision import HumanDetect

from .test_platform_agent import _platform as bare_platform, _token


@contextlib.asynccontextmanager
async def _platform(settings, unique, **kw):
    """test_platform_agent's Platform and client, with the pool started and a token for "ann"."""
    async with bare_platform(settings, unique, **kw) as (platform, client):
        assert await asyncio.to_thread(platform.service_pool.wait_ready, 60)
        yield platform, client, await _token(client, platform, "ann")


def _room(token: str, wall_across: bool = False) -> UploadMap:
    """A 4 m x 4 m room (walls round it); `wall_across`: a wall splits it in two."""
    blocked = np.zeros((80, 80), bool)
    blocked[0, :] = blocked[-1, :] = blocked[:, 0] = blocked[:, -1] = True
    if wall_across:
        blocked[:, 40] = True
    png, yaml_text = encode_map(blocked, 0.05)
    return UploadMap(token=token, map_id="room", png_b64=base64.b64encode(png).decode(), yaml_text=yaml_text)


def _plan(token: str) -> PlanPath2D:
    return PlanPath2D(token=token, robot_type="nao", map_id="room", start=Pose2D(x=0.7, y=2.0), goal=Pose2D(x=3.3, y=2.0))


def _image(w: int, h: int, seed: int = 1) -> str:
    """Rectangles of random grey on white: edges for the detectors, a small PNG."""
    rng = np.random.default_rng(seed)
    img = np.full((h, w, 3), 255, np.uint8)
    for _ in range(60):
        x, y = int(rng.integers(0, w - 10)), int(rng.integers(0, h - 10))
        cv2.rectangle(img, (x, y), (x + int(rng.integers(5, w // 4)), y + int(rng.integers(5, h // 4))),
                      tuple(int(c) for c in rng.integers(0, 200, 3)), -1)
    return encode_image(img)


async def test_cpu_bound_services_run_in_worker_processes_and_a_map_crosses_once(settings, unique):
    async with _platform(settings, unique, service_workers=1) as (platform, client, token):
        pool = platform.service_pool
        img = _image(320, 240)
        await client.request(platform.address, DoorCheck(token=token, image_b64=img), timeout=30)
        await client.request(platform.address, LightCheck(token=token, image_b64=img), timeout=30)
        await client.request(platform.address, WeatherCurrent(token=token, city="Warsaw"))  # a thread's
        assert sum(pool.calls_by_pid.values()) == 2
        assert set(pool.calls_by_pid) == set(pool.pids) and os.getpid() not in pool.calls_by_pid
        await client.request(platform.address, _room(token))
        for _ in range(3):
            plan = await client.request(platform.address, _plan(token), timeout=30)
            assert plan.plan_found == PLAN_FOUND
        assert pool.map_sends == 1  # cached in the worker by its content
        await client.request(platform.address, _room(token, wall_across=True))  # same id, other grid
        plan = await client.request(platform.address, _plan(token), timeout=30)
        assert plan.plan_found == PLAN_NOT_FOUND and pool.map_sends == 2


async def test_a_killed_worker_fails_its_call_clearly_and_is_replaced(settings, unique):
    async with _platform(settings, unique, service_workers=1) as (platform, client, token):
        pool = platform.service_pool
        [pid] = pool.pids
        slow = asyncio.create_task(client.request(platform.address, HumanDetect(token=token, image_b64=_image(640, 480)),
                                                  timeout=60))
        for _ in range(500):  # HOG on 640x480 noise takes ~1 s: kill it while it runs
            if pool.busy_pids():
                break
            await asyncio.sleep(0.01)
        os.kill(pid, signal.SIGKILL)
        with pytest.raises(RequestFailed, match=r"service worker process \(pid \d+\) running human_detection died"):
            await slow
        light = await client.request(platform.address, LightCheck(token=token, image_b64=_image(64, 48)), timeout=30)
        assert 0 <= light.light_level <= 100
        assert pool.pids and pool.pids[0] != pid and pool.restarts == 1
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)  # reaped, not a zombie of ours


async def test_workers_are_gone_after_the_platform_stops(settings, unique):
    async with _platform(settings, unique, service_workers=2) as (platform, client, token):
        pids = list(platform.service_pool.pids)
        assert len(pids) == 2
    await asyncio.sleep(0.2)
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


def test_bad_images_are_service_errors_in_a_worker_too():
    """The pool gives back a ServiceError's reason and code as the service raised them."""
    from agents.services.context import ServiceContext, ServiceState
    from agents.services.errors import ServiceError
    from agents.services.pool import ServicePool

    async def run():
        pool = ServicePool(1, name="test")
        pool.start()
        try:
            ctx = ServiceContext("ann", ServiceState())
            with pytest.raises(ServiceError, match="could not be decoded") as e:
                await pool.run("hazard_detection_light_check", LightCheck(image_b64=base64.b64encode(b"junk").decode()), ctx)
            assert e.value.code == "bad_image"
        finally:
            await asyncio.to_thread(pool.close)

    asyncio.run(run())


def test_a_pooled_speech_recognition_fills_a_slot_with_the_callers_rooms():
    """The rooms live in the Platform's state, the decoder in a worker: the call takes them along."""
    from agents.services.context import ServiceContext, ServiceState
    from agents.services.pool import ServicePool
    from agents.services.speech import SpeechRecognition
    from ontology.services.home import HomeInfo, RoomSpec, UploadHomeInfo
    from agents.services import run_service
    from hearing.wav import encode_wav

    from .services.test_speech import _heard

    pytest.importorskip("espeakng_loader")
    wav = base64.b64encode(encode_wav(_heard("check the lamps in the kitchen")[1])).decode()
    req = SpeechRecognition(audio_b64=wav, sentences=["check the hazards", "check the lamps in the {room}"])

    async def run():
        pool = ServicePool(1, name="test")
        pool.start()
        try:
            ctx = ServiceContext("ann", ServiceState())
            run_service("home_upload_info", UploadHomeInfo(info=HomeInfo(
                home_id="home", map_id="m", rooms=[RoomSpec(name="kitchen", rect=[0, 0, 1, 1])])), ctx)
            return (await pool.run("speech_recognition", req, ctx)).text
        finally:
            await asyncio.to_thread(pool.close)

    assert asyncio.run(run()) == "check the lamps in the kitchen"

