"""The owner's voice in a run: scenario-file speech lines, `rapp say` into a running run's inbox, and
a whole run whose command is only spoken (the Core hears it through the NAO's microphone)."""
import asyncio
import json
import re
import os
from pathlib import Path

import numpy as np
import pytest

from cli.main import main as cli
from robots import RobotAPI, World
from robots.sound import house_sound
from scenarios.owner_voice import (OwnerVoice, ScriptError, SpokenLine, announce_run, load_script, post_line,
                                   retire_run, running_inbox)
from scenarios.run_rapp import run_rapp

HELLO = Path(__file__).resolve().parents[1] / "rapps" / "examples" / "hello"


@pytest.fixture(autouse=True)
def own_runtime_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "runtime"))


def test_script_lines_sorted_and_checked(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("disturbances: []\nspeech:\n  - {at: 9, say: check the hazards, distance: 2}\n  - {say: hello}\n")
    lines = load_script(f)
    assert [(x.at, x.say, x.distance) for x in lines] == [(0.0, "hello", 1.0), (9.0, "check the hazards", 2.0)]
    for text, msg in (("speech: {say: hi}", "must be a list"), ("- a\n- b", "expected a mapping"),
                      ("speech:\n  - {say: hi, at: -1}", "speech[0].at"), ("speech:\n  - {say: hi, loud: 1}", "speech[0].loud"),
                      ("speech: [", "cannot read")):
        f.write_text(text)
        with pytest.raises(ScriptError, match=re.escape(msg)):
            load_script(f)


def test_rapp_say_finds_the_running_run(tmp_path, capsys):
    with pytest.raises(ScriptError, match="no `rapp run` is running"):
        running_inbox()
    assert cli(["say", "hello"]) == 1 and "no `rapp run` is running" in capsys.readouterr().err
    out = tmp_path / "run"
    (out / "inbox").mkdir(parents=True)
    announce_run(out)
    assert cli(["say", "check the hazards", "--distance", "2.5"]) == 0
    [posted] = list((out / "inbox").glob("*.json"))
    assert SpokenLine.model_validate_json(posted.read_text()).distance == 2.5
    assert cli(["say", "hi", "--distance", "50"]) == 1 and "distance" in capsys.readouterr().err
    pointer = json.loads((tmp_path / "runtime" / "rapp" / "current-run.json").read_text())
    pointer["pid"] = 2 ** 22 + 1  # above pid_max: no such process
    (tmp_path / "runtime" / "rapp" / "current-run.json").write_text(json.dumps(pointer))
    with pytest.raises(ScriptError, match="has ended"):
        post_line(SpokenLine(say="hi"))
    with pytest.raises(ScriptError, match="not a running"):
        post_line(SpokenLine(say="hi"), run=tmp_path)
    announce_run(tmp_path / "newer")
    retire_run(out)
    assert (tmp_path / "runtime" / "rapp" / "current-run.json").exists()  # a newer run's pointer stays
    announce_run(out)
    retire_run(out)
    assert not (tmp_path / "runtime" / "rapp" / "current-run.json").exists()


def test_rapp_say_refuses_a_finished_run_and_an_unknown_voice(tmp_path, capsys):
    # a finished run's folder keeps its inbox: a line dropped there was never said, and the user was
    # told "said into"
    pytest.importorskip("espeakng_loader")
    out = tmp_path / "run"
    OwnerVoice(None, None, out)  # what a run does when it starts serving its inbox
    assert cli(["say", "hello", "--run", str(out)]) == 0  # this process is alive: it serves
    (out / "inbox" / ".pid").write_text(str(2 ** 22 + 1))  # above pid_max: no such process
    assert cli(["say", "hello", "--run", str(out)]) == 1 and "has ended" in capsys.readouterr().err
    (out / "inbox" / ".pid").write_text(str(os.getpid()))
    assert cli(["say", "hello", "--voice", "xx-nobody", "--run", str(out)]) == 1
    assert "unknown voice 'xx-nobody'" in capsys.readouterr().err
    assert len(list((out / "inbox").glob("*.json"))) == 1  # only the first line was posted


@pytest.mark.slow  # 60 s: the inbox and the script are each tested alone above
async def test_inbox_and_script_play_one_line_after_another(tmp_path):
    world = World.from_file("small", seed=3)
    try:
        api = RobotAPI(world.add_robot("nao"))
        voice = OwnerVoice(world, api, tmp_path, log=lambda *_: None)
        (voice.inbox / "bad.json").write_text("{not json")
        post_line(SpokenLine(say="hello robot"), run=tmp_path)
        server = asyncio.create_task(voice.serve_inbox())
        # the inbox line first (its synthesis takes wall time; an unpaced world would reach the
        # script's 2 s before it on a loaded machine), then the script's line while it still plays
        for _ in range(300):
            if voice.spoken:
                break
            await asyncio.sleep(0.05)
        script = asyncio.create_task(voice.run_script([SpokenLine(say="check the hazards", at=2.0, distance=3.0)]))
        # bounded in wall time: the line's synthesis runs in a thread, and 200 steps of the unpaced
        # world took less than that synthesis on a loaded machine (CI saw the script's line missing)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 60.0
        while not (script.done() and not list(voice.inbox.iterdir())) and loop.time() < deadline:
            await world.sleep(0.1)
        server.cancel()
        assert [s["say"] for s in voice.spoken] == ["hello robot", "check the hazards"]
        first, second = voice.spoken
        assert second["t"] >= 2.0 and second["distance"] == 3.0
        clips = {k: v for k, v in house_sound(world).sources.items() if k.startswith("owner-")}
        assert len(clips) == 2
        ends = sorted((c.start, c.end()) for c in clips.values())
        assert ends[0][1] <= ends[1][0]  # one mouth: the second line starts after the first ended
        pcm = house_sound(world).receive(api.audio_in.position(), ends[0][0], ends[0][1] - ends[0][0])
        assert np.abs(pcm).max() > 300  # the robot's microphone really gets the owner's words
    finally:
        world.close()


@pytest.mark.timeout(180)
async def test_a_run_whose_command_is_only_spoken(tmp_path):
    out = tmp_path / "out"

    async def owner():
        while not (out / "inbox").is_dir() or not os.path.exists(os.environ["XDG_RUNTIME_DIR"] + "/rapp/current-run.json"):
            await asyncio.sleep(0.2)
        await asyncio.sleep(0.5)  # the pointer is written once the Core's ear is open
        assert cli(["say", "hello"]) == 0

    speaker = asyncio.create_task(owner())
    result = await run_rapp(HELLO, "nao", "small", 1, None, out, timeout_s=90, listen=True)
    await speaker
    assert result["ok"], result["end"]
    assert [s["say"] for s in result["spoken"]] == ["hello"]
    trace = (out / "trace.jsonl").read_text()
    assert '"s4a_keyword"' in trace  # heard as an isolated keyword on the robot, not typed
    assert not (Path(os.environ["XDG_RUNTIME_DIR"]) / "rapp" / "current-run.json").exists()
