"""A Platform that remembers (issue 47, item 2): `rapp agent platform --data DIR` is a real process on
the test's XMPP server; the owner's first run uploads a map and a home, teaches an object, a face and
rooms, records a cognitive score and marks an obstacle; the Platform is killed (SIGKILL: no clean
stop) and started again on the same directory; the owner's second run finds every datum."""
from __future__ import annotations

import base64
import os
import signal
from pathlib import Path

from agents.base import RappAgent
from ontology import platform as P
from ontology.services.home import GetHomeInfo, HomeInfo, RoomSpec, UploadHomeInfo
from ontology.services.knowledge import ChooseCognitiveTest, GetHistory, RecordPerformance
from ontology.services.navigation import AddObstacle, ListMaps, ListObstacles
from ontology.services.vision import (FindObjects, LearnFace, LearnObject, LearnScene, RecognizeFaces,
                                     RecognizeScene)
from scenarios.launch import LoggedProcesses

from .services.test_saved import _map_request
from .test_cli import RAPP

DATA = Path(__file__).resolve().parent / "data"


def _b64(name: str) -> str:
    return base64.b64encode((DATA / name).read_bytes()).decode("ascii")


class _Platform(LoggedProcesses):
    def __init__(self, tmp: Path, settings, name: str):
        env = {k: v for k, v in os.environ.items() if not k.startswith("RAPP_") or k == "RAPP_TEST_RUN"}  # (the watchdog's mark stays)
        env.update(RAPP_XMPP_HOST=settings.host, RAPP_XMPP_PORT=str(settings.port), RAPP_XMPP_DOMAIN=settings.domain,
                   RAPP_CREDENTIALS_DIR=str(tmp / "credentials"), XDG_DATA_HOME=str(tmp / "xdg"))
        super().__init__(tmp, env, RAPP)
        self.name, self.data, self.runs = name, tmp / "platform-data", 0

    async def up(self) -> None:
        self.runs += 1
        log = f"platform-{self.runs}"
        self.start(log, "agent", "platform", "--name", self.name, "--data", str(self.data), "--allow-unsandboxed",
                   "--service-workers", "1", "--warm-workers", "0")
        await self.wait_log(log, "running", timeout=90)

    def kill(self) -> None:
        proc = self.procs[f"platform-{self.runs}"]
        os.killpg(proc.pid, signal.SIGKILL)  # the Platform and its service workers, no clean stop
        proc.wait(10)


async def test_a_killed_platform_keeps_every_datum_of_its_owner(settings, unique, tmp_path):
    platform = _Platform(tmp_path, settings, unique("platform"))
    owner = RappAgent(unique("owner"), settings)
    try:
        await platform.up()
        await owner.start()
        to = f"{platform.name}@{settings.domain}"

        async def call(req, token):
            req.token = token
            return await owner.request(to, req, timeout=60)

        # the first run of the owner
        await owner.request(to, P.RegisterUser(user="ann", password="pw"))
        token = (await owner.request(to, P.Login(user="ann", password="pw"))).token
        upload, blocked = _map_request("flat")
        await call(upload, token)
        home = HomeInfo(home_id="home", map_id="flat", rooms=[RoomSpec(name="kitchen", rect=[0, 0, 2, 2])])
        await call(UploadHomeInfo(info=home), token)
        await call(LearnObject(name="mug", image_b64=_b64("coffee.jpg")), token)
        # a face learned in the service pool's worker, kept by the Platform
        await call(LearnFace(name="Barack", images_b64=[_b64("faces/obama-1.jpg")]), token)
        await call(LearnScene(room="kitchen", images_b64=[_b64("coffee.jpg")]), token)
        await call(LearnScene(room="study", images_b64=[_b64("cameraman.jpg")]), token)
        test = await call(ChooseCognitiveTest(test_type="arithmetic"), token)
        await call(RecordPerformance(test_id=test.test_id, score=90), token)
        mark = await call(AddObstacle(map_id="flat", x=2.0, y=0.5, radius_m=0.3, ttl_s=900, note="box"), token)

        platform.kill()
        await platform.up()

        # the second run: a new login, and the old token still good
        again = (await owner.request(to, P.Login(user="ann", password="pw"))).token
        assert [m.map_id for m in (await call(ListMaps(), again)).maps] == ["flat"]
        assert await call(GetHomeInfo(home_id="home"), token) == home
        found = (await call(FindObjects(image_b64=_b64("coffee.jpg")), again)).objects
        assert [f.name for f in found] == ["mug"]
        assert [r.score for r in (await call(GetHistory(), again)).records] == [90]
        faces = (await call(RecognizeFaces(image_b64=_b64("faces/obama-2.jpg")), again)).faces
        assert [f.name for f in faces] == ["Barack"]
        assert (await call(RecognizeScene(images_b64=[_b64("cameraman.jpg")]), again)).room == "study"
        marks = (await call(ListObstacles(map_id="flat"), again)).obstacles
        assert [(k.id, k.note) for k in marks] == [(mark.added, "box")]
    finally:
        await owner.stop()
        platform.stop_all()
