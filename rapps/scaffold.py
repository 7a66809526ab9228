"""`rapp new NAME [DIR] [--cloud]`: a RApp package to start from: manifest, a task with a two-state
FSM, optionally a Cloud Agent part, a test that runs it on the simulated robot, and a test that replays
a recorded run of it once one is saved in its tests/recording (rapps/sdk/testing.py). It builds,
publishes and runs unchanged (`rapp run rapp DIR`)."""
from __future__ import annotations

import re
from pathlib import Path

from ontology import robot_types

MANIFEST = """\
# {name}: made by `rapp new`. Fields: docs/sdk.md and ontology/manifest.py.
name: {name}
version: 0.1.0
description: {title} (edit me).
robot_types: [{robot_types}]
keywords: [{keyword}]
phrases:
  - run {words}
entry_point: {pkg}.task:{cls}Task
{cloud_line}services: [ping]
robot_api: [communication, navigation, vision]
params:
  greeting: Hello from {name}
time_limit_s: 120
author: you
"""

TASK = '''\
"""{title}: two behaviours, greet then report (edit them)."""
from rapps.sdk import FSM, Step, Task
{cloud_import}

class {cls}Task(Task):
{cloud_attr}    def build(self):
        fsm = FSM("{pkg}", initial="greet")
        fsm.add_state("greet", Step(self.greet))
        fsm.add_state("report", Step(self.finish), final=True)
        fsm.add_transition("greet", "report")
        return fsm

    async def greet(self, memory):
        await self.say(str(self.params["greeting"]))  # an Elektron has no speech: nothing is said
        memory["pose"] = (await self.robot.get_global_pose()).model_dump()
        image = await self.robot.capture_image()  # `rapp run rapp` keeps it in its frames/ folder
        memory["image"] = f"{{image.width}}x{{image.height}}"

    async def finish(self, memory):
        pong = await self.platform.ping()
{cloud_call}        await self.report(f"{name} done for {{pong.user}} at {{memory['pose']}}, saw {{memory['image']}}", **extra)
'''

MODELS = '''\
from ontology.registry import Action, Content, action

ONTOLOGY = "cloud.{name}"


class Doubled(Content):
    value: int


@action("double", ontology=ONTOLOGY, reply=Doubled)
class Double(Action):
    value: int
'''

CLOUD = '''\
"""The Cloud Agent part of {name}: runs on the Platform, serves only this RApp's Dynamic Agent."""
from rapps.sdk import CloudService

from .models import ONTOLOGY, Doubled


class {cls}Cloud(CloudService):
    ontology = ONTOLOGY

    async def double(self, req):
        return Doubled(value=req.value * 2)
'''

TEST = '''\
"""Runs {name} on the simulated robot: `rapp test` on its folder, or `pytest {rel}`. The Store runs it
once per robot type of the manifest (RAPP_ROBOT_TYPE) and lists the RApp for the types that pass."""
import json
import os
from pathlib import Path

import pytest

from scenarios.run_rapp import run_rapp

HERE = Path(__file__).resolve().parent.parent
ROBOT = os.environ.get("RAPP_ROBOT_TYPE", "nao")  # `rapp test DIR --robot elektron`; the Store's build sets it
pytestmark = pytest.mark.asyncio  # pytest-asyncio runs it (`rapp test DIR` needs no mark)


async def test_{pkg}_runs_on_a_simulated_robot(tmp_path):
    result = await run_rapp(HERE, ROBOT, "small", 1, None, tmp_path, timeout_s=120)
    assert result["ok"], result["end"]
    assert any("{name} done" in r["text"] for r in result["reports"])
    assert json.loads((tmp_path / "result.json").read_text())["ok"]
'''


REPLAY_TEST = '''\
"""Replays the recorded run in tests/recording against this source and fails on the first divergence
(docs/sdk.md "A recording as a test"). It waits for a recording; in this RApp's folder make one and keep it:
    rapp run rapp . --out /tmp/run
    rapp replay /tmp/run --save tests/recording
"""
from pathlib import Path

import pytest

from rapps.sdk.testing import assert_replays, has_recording

HERE = Path(__file__).resolve().parent.parent
RECORDING = HERE / "tests" / "recording"
pytestmark = pytest.mark.asyncio


@pytest.mark.skipif(not has_recording(RECORDING), reason="no recording yet: rapp run rapp DIR --out RUN, "
                                                         "then rapp replay RUN --save DIR/tests/recording")
async def test_{pkg}_behaves_as_recorded():
    await assert_replays(RECORDING, HERE)
'''


def create(name: str, directory: str | Path | None = None, cloud: bool = False) -> Path:
    if not re.fullmatch(r"[a-z][a-z0-9-]{1,40}", name):
        raise ValueError(f"a RApp name is lower-case letters, digits and dashes, starting with a letter: {name!r}")
    dest = Path(directory or name)
    if dest.exists() and any(dest.iterdir()):
        raise FileExistsError(f"{dest} exists and is not empty")
    pkg = name.replace("-", "_")
    cls = "".join(w.capitalize() for w in name.split("-"))
    title = name.replace("-", " ").capitalize()
    fill = dict(name=name, pkg=pkg, cls=cls, title=title, keyword=name.replace("-", ""),
                robot_types=", ".join(robot_types.names()),  # every type of ontology/robot_types.py
                words=name.replace("-", " "), rel=f"{dest}/tests",
                cloud_line=f"cloud_entry_point: {pkg}.cloud:{cls}Cloud\n" if cloud else "",
                cloud_import="\nfrom .models import ONTOLOGY\n" if cloud else "",
                cloud_attr="    cloud_ontology = ONTOLOGY\n\n" if cloud else "",
                cloud_call=("        extra = {\"doubled\": (await self.cloud.call(\"double\", value=21)).value}\n"
                            if cloud else "        extra = {}\n"))
    (dest / pkg).mkdir(parents=True, exist_ok=True)
    (dest / "tests").mkdir(exist_ok=True)
    (dest / "manifest.yaml").write_text(MANIFEST.format(**fill))
    (dest / pkg / "__init__.py").write_text("")
    (dest / pkg / "task.py").write_text(TASK.format(**fill))
    if cloud:
        (dest / pkg / "models.py").write_text(MODELS.format(**fill))
        (dest / pkg / "cloud.py").write_text(CLOUD.format(**fill))
    (dest / "tests" / f"test_{pkg}.py").write_text(TEST.format(**fill))
    (dest / "tests" / f"test_{pkg}_replay.py").write_text(REPLAY_TEST.format(**fill))
    return dest
