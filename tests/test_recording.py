"""Every run a recording (issue 45): the whole message bodies with secrets as placeholders, run.mcap
read back with the mcap reader (each channel's schema and count), `rapp replay` against the
recording (no divergence; a changed RApp's first divergence, both sides), and re-simulation.

One recorded run of tests/fixtures/recorded_app on the small house (a step with progress, an
estimate, a frame, the Platform, its Cloud Agent) serves the module; the re-simulation is a second run."""
from __future__ import annotations

import asyncio
import contextlib
import io
import json
import os
import shutil
from pathlib import Path

import pytest
from mcap.reader import make_reader

from agents.tracing import (BLOBS, BODIES, BlobStore, TraceRelay, TraceWriter, inflate, is_placeholder, mask_secrets,
                            placeholder, record_bodies, stop_recording_bodies)
from rapps.replay import RecordingError, first_difference, load_recording, replay
from scenarios import resim
from scenarios.run_rapp import run_rapp

from .test_cli import arapp, rapp

APP = Path(__file__).resolve().parent / "fixtures" / "recorded_app"


# -- secrets, blobs and the relay -------------------------------------------------------------------
def test_secrets_become_stable_placeholders_that_say_nothing_of_them():
    body = json.dumps({"token": "tok-123456", "inner": {"password": "hunter2", "keep": "x"},
                       "list": [{"token": "tok-123456"}], "empty": {"token": ""}})
    masked = mask_secrets(body)
    assert "tok-123456" not in masked and "hunter2" not in masked
    data = json.loads(masked)
    assert data["token"] == data["list"][0]["token"] == placeholder("tok-123456")  # stable
    assert is_placeholder(data["inner"]["password"]) and data["inner"]["password"] != data["token"]
    assert data["inner"]["keep"] == "x" and data["empty"]["token"] == ""  # no secret, nothing to hide
    text = mask_secrets('not json "password": "pa\\"ss" rest')  # an escaped quote does not end the value early
    assert text == 'not json "password": "' + placeholder('pa\\"ss') + '" rest'
    assert mask_secrets('{"a": 1}') == '{"a": 1}'


def test_blobs_are_kept_once_and_inflate_back(tmp_path):
    store = BlobStore(tmp_path / "blobs")
    image = "A" * 5000
    body = json.dumps({"data_b64": image, "small": "b" * 10})
    out = store.extract(body)
    assert image not in out and "<blob:" in out and len(list((tmp_path / "blobs").iterdir())) == 1
    assert store.extract(json.dumps({"again": image})).count("<blob:") == 1
    assert len(list((tmp_path / "blobs").iterdir())) == 1  # the same string: one file
    assert json.loads(inflate(out, tmp_path / "blobs")) == json.loads(body)


async def test_a_rapps_bodies_are_masked_and_stamped_by_its_relay(tmp_path):
    trace = tmp_path / "trace.jsonl"
    writer = record_bodies(trace)
    try:
        r, w = os.pipe()
        relay = TraceRelay(r, writer, who=lambda: "dyn-x@localhost", pid=lambda: 4242)
        relay.start(asyncio.get_running_loop())
        rapp_side = TraceWriter(None, w)
        rapp_side.bodies = rapp_side  # as agents/runtime.py sets it for a recorded run
        rapp_side.body("send", "core-nao1@localhost", "core-nao1@localhost", "platform@localhost", "request", "c-1",
                       "platform", "ping", "m-1", "", json.dumps({"token": "secret-tok", "image": "Z" * 5000}))
        rapp_side.close()
        for _ in range(100):
            if relay._loop is None:  # the pipe's end read: closed
                break
            await asyncio.sleep(0.02)
        [rec] = [json.loads(line) for line in (tmp_path / BODIES).read_text().splitlines()]
        assert rec["origin"] == rec["agent"] == "dyn-x@localhost" and rec["claimed_agent"] == "core-nao1@localhost"
        assert rec["pid"] == 4242 and "secret-tok" not in json.dumps(rec)
        body = json.loads(inflate(rec["body"], tmp_path / BLOBS))
        assert is_placeholder(body["token"]) and body["image"] == "Z" * 5000
    finally:
        stop_recording_bodies(trace)
        writer.close()


def test_a_rapps_records_cannot_put_words_on_another_agents_channel(tmp_path):
    """run.mcap is assembled from the trace, where a RApp's lines come through its relay stamped with
    its `origin`: they count for the messages it sent itself, never as its Core's (a forged record or
    body of the Core's, which the relay does not stop, stays out of /acl/core-nao1)."""
    from scenarios.mcap_export import export_mcap

    core, dyn = "core-nao1@localhost", "dyn-nao1-x-1@localhost"

    def msg(t, direction, sender, receiver, mid, content, **kw):
        return {"t": t, "kind": "message", "pid": 1, "agent": kw.pop("agent", sender), "dir": direction,
                "sender": sender, "receiver": receiver, "performative": "inform", "conversation_id": "c-1",
                "ontology": "core", "action": "get_global_pose", "message_id": mid, "in_reply_to": "",
                "content": json.dumps(content), "size": 9, **kw}

    records = [msg(1.0, "send", core, dyn, "m-1", {"x": 1}),  # the Core's own record
               msg(1.1, "recv", dyn, core, "m-1", {"x": 1}, agent=dyn, origin=dyn),  # the RApp's, of the same
               # the RApp's own message, as it claims to have sent it and as its Core received it
               msg(2.0, "send", dyn, core, "m-2", {"ask": "rewritten"}, agent=dyn, origin=dyn),
               msg(2.1, "recv", dyn, core, "m-2", {"ask": 1}, agent=core),
               msg(2.5, "send", dyn, "platform@localhost", "m-5", {"ping": 1}, agent=dyn, origin=dyn),  # no one else saw
               # forged by the RApp: the Core "sending" and a reception "from" the Core it never sent
               msg(0.5, "send", core, dyn, "m-3", {"forged": True}, agent=dyn, origin=dyn, claimed_agent=core),
               msg(3.0, "recv", core, dyn, "m-4", {"forged": True}, agent=dyn, origin=dyn)]
    (tmp_path / "trace.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    bodies = [{"kind": "body", "t": 1.0, "dir": "send", "agent": core, "sender": core, "receiver": dyn,
               "message_id": "m-1", "body": json.dumps({"x": 1})},
              {"kind": "body", "t": 1.2, "dir": "recv", "agent": dyn, "origin": dyn, "sender": core, "receiver": dyn,
               "message_id": "m-1", "body": json.dumps({"x": 666})},  # later: it would have won
              {"kind": "body", "t": 1.3, "dir": "send", "agent": dyn, "origin": dyn, "sender": core, "receiver": dyn,
               "message_id": "m-1", "body": json.dumps({"x": 667})}]
    (tmp_path / BODIES).write_text("".join(json.dumps(b) + "\n" for b in bodies))
    path = export_mcap(tmp_path)
    from_core = _messages(path, "/acl/core-nao1")
    assert [(m["message_id"], m["content"]) for m in from_core] == [("m-1", {"x": 1})]
    # what the Core received, not the RApp's account of it; the RApp's own record where no trusted agent has one
    assert [(m["message_id"], m["content"]) for m in _messages(path, "/acl/dyn-nao1-x-1")] == [("m-2", {"ask": 1}),
                                                                                              ("m-5", {"ping": 1})]


def test_comparison_follows_placeholders_consistently():
    seen: dict = {}
    p = placeholder("t1")
    assert first_difference({"token": p, "x": 1}, {"token": "replay-a", "x": 1}, seen) is None
    assert first_difference({"token": p}, {"token": "replay-b"}, seen)  # the same secret, another value
    assert "in the replay only" in first_difference({"a": 1}, {"a": 1, "b": 2}, {})
    assert ".a[1]" in first_difference({"a": [1, 2]}, {"a": [1, 3]}, {})
    assert first_difference({"a": 1.0}, {"a": 1}, {}) is None


def test_a_folder_without_a_recording_is_refused_clearly(tmp_path):
    with pytest.raises(RecordingError, match="no trace.jsonl"):
        load_recording(tmp_path)
    (tmp_path / "trace.jsonl").write_text("")
    with pytest.raises(RecordingError, match="not recorded"):
        load_recording(tmp_path)
    res = rapp("replay", tmp_path)
    assert res.returncode == 1 and "not recorded" in res.stderr and "Traceback" not in res.stderr


# -- a recorded run -------------------------------------------------------------------------------
PRINTED: list[str] = []  # what the recorded run printed on stdout


@pytest.fixture(scope="module")
async def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("recorded")
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):  # without progress, as `rapp run rapp --quiet` runs it
        result = await run_rapp(APP, "nao", "small", 3, None, out, timeout_s=240)
    assert result["ok"], result["end"]
    PRINTED.append(printed.getvalue())
    return out, result


async def test_a_run_without_progress_prints_nothing_while_it_runs(recorded):
    """`--quiet`: nothing until the closing summary (it printed "[run] nao in small: owner says ...")."""
    assert PRINTED == [""]


def _channels(path: Path) -> dict[str, tuple[str, str, str, int]]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return {c.topic: (summary.schemas[c.schema_id].name, summary.schemas[c.schema_id].encoding, c.message_encoding,
                      summary.statistics.channel_message_counts[i]) for i, c in summary.channels.items()}


async def test_the_run_mcap_has_each_channel_with_its_schema(recorded):
    out, result = recorded
    channels = _channels(out / "run.mcap")
    dyn = load_recording(out).dynamic.split("@")[0]
    expect = {"/map": "foxglove.Grid", "/tf": "foxglove.FrameTransforms", "/nao/pose": "foxglove.PoseInFrame",
              "/nao/estimate": "foxglove.PoseInFrame", "/nao/path": "foxglove.PosesInFrame",
              "/nao/camera": "foxglove.CompressedImage", "/log": "foxglove.Log", "/events": "foxglove.Log",
              "/chat": "foxglove.Log", f"/acl/{dyn}": "rapp.AclMessage", "/acl/core-nao1": "rapp.AclMessage"}
    for topic, schema in expect.items():
        assert topic in channels, f"{topic} missing: {sorted(channels)}"
        assert channels[topic][:3] == (schema, "jsonschema", "json"), topic
    counts = {t: c[3] for t, c in channels.items()}
    assert counts["/map"] == 1 and counts["/nao/estimate"] == 1 and counts["/nao/path"] == 1
    assert counts["/nao/camera"] == len(result["frames"]) == 1
    poses = [p for p in _robot(out) if p["kind"] == "pose"]
    # one pose each 0.2 simulated s, taken by a task that wakes after the world passed the time: on a
    # loaded machine the world runs ahead between wake-ups (a clean CI run gave 63 for 15.85 s)
    assert counts["/nao/pose"] == counts["/tf"] == len(poses) and len(poses) >= result["duration_sim_s"] / 0.2 * 0.6
    sent = {r["message_id"] for r in _trace(out) if r["kind"] == "message" and r["dir"] == "send"
            and r["sender"].startswith(dyn)}
    assert counts[f"/acl/{dyn}"] == len(sent)  # each of its messages once, heartbeats included
    acl, camera = _messages(out / "run.mcap", f"/acl/{dyn}"), _messages(out / "run.mcap", "/nao/camera")
    with open(out / "run.mcap", "rb") as f:  # every channel's first messages against the schema the file carries
        reader = make_reader(f)
        seen: dict[str, int] = {}
        for schema, channel, message in reader.iter_messages():
            if seen.get(channel.topic, 0) >= 3:
                continue
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
            text = json.loads(schema.data)
            bad = _conforms(json.loads(message.data), text, text.get("$defs", {}), channel.topic)
            assert not bad, bad
    report = next(m for m in acl if m["action"] == "report")
    assert report["content"]["data"] == {"doubled": 42, "user": "owner-nao1"} and not report["truncated"]
    assert camera[0]["format"] in ("png", "jpeg") and len(camera[0]["data"]) > 1000  # the frame itself


def _conforms(value, schema: dict, defs: dict, where: str = "") -> list[str]:
    """What in `value` breaks a JSON Schema's types, required properties and enumerations (the parts
    Foxglove's schemas use; a reader like Foxglove or Lichtblick relies on exactly these)."""
    if "$ref" in schema:
        schema = defs[schema["$ref"].rsplit("/", 1)[-1]]
    if "oneOf" in schema:  # Foxglove's enumerations: one const each
        consts = [o.get("const") for o in schema["oneOf"]]
        return [] if value in consts else [f"{where}: {value!r} not one of {consts}"]
    types = schema.get("type")
    types = [types] if isinstance(types, str) else types or []
    checks = {"object": lambda v: isinstance(v, dict), "array": lambda v: isinstance(v, list),
              "string": lambda v: isinstance(v, str), "boolean": lambda v: isinstance(v, bool),
              "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
              "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool), "null": lambda v: v is None}
    if types and not any(checks[t](value) for t in types):
        return [f"{where}: {type(value).__name__} is not {types}"]
    bad = []
    if isinstance(value, dict):
        bad += [f"{where}.{k}: missing" for k in schema.get("required", []) if k not in value]
        for k, sub in schema.get("properties", {}).items():
            if k in value:
                bad += _conforms(value[k], sub, defs, f"{where}.{k}")
    if isinstance(value, list) and "items" in schema:
        for i, item in enumerate(value[:20]):
            bad += _conforms(item, schema["items"], defs, f"{where}[{i}]")
    return bad


def _messages(path: Path, topic: str) -> list[dict]:
    with open(path, "rb") as f:
        return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic])]


def _trace(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "trace.jsonl").read_text().splitlines() if line.strip()]


def _robot(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "robot.jsonl").read_text().splitlines() if line.strip()]


async def test_no_secret_is_written_and_the_package_is_kept(recorded):
    out, _ = recorded
    values = []
    for line in (out / BODIES).read_text().splitlines():
        body = json.loads(line)["body"]
        for key in ("token", "password"):
            values += [v for v in _field_values(_json(body), key) if v]
    assert values and all(is_placeholder(v) for v in values), values[:5]
    for name in ("trace.jsonl", BODIES, "robot.jsonl", "run.mcap"):
        assert b"developer-secret" not in (out / name).read_bytes(), name  # the Store owner's password
    rec = load_recording(out)
    assert rec.package is not None and rec.package.stat().st_mode & 0o077 == 0
    assert (out / BODIES).stat().st_mode & 0o077 == 0


def _json(text: str):
    try:
        return json.loads(text)
    except ValueError:
        return None


def _field_values(value, key: str) -> list:
    if isinstance(value, dict):
        return [v for k, v in value.items() if k == key] + [x for v in value.values() for x in _field_values(v, key)]
    if isinstance(value, list):
        return [x for v in value for x in _field_values(v, key)]
    return []


async def test_replay_finds_no_divergence_and_is_fast(recorded):
    out, result = recorded
    res = await replay(out, mode="inprocess", stall_s=20)
    assert res.ok, res.summary()
    assert res.end == "Finished" and res.requests >= 10 and res.delivered >= res.requests
    assert "no divergence" in res.summary()


async def test_a_corrupt_recorded_package_fails_the_replay_and_leaves_nothing(recorded, tmp_path, monkeypatch):
    """The package's unpacking and the replay's server start run together: a package that fails to
    unpack ends the replay with that error only after the server has started, and the clean-up then
    stops it and removes the work folder (nothing of the replay is left)."""
    import tempfile

    out, _ = recorded
    copy = tmp_path / "copy"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("frames", "system"))
    for package in (copy / "packages").glob("*.rapp"):
        package.write_bytes(b"not a package" * 100)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    with pytest.raises(Exception) as failed:
        await replay(copy, mode="inprocess")
    assert not isinstance(failed.value, RecordingError) or "package" in str(failed.value)
    assert list((tmp_path / "tmp").iterdir()) == []
    me = str(os.getpid())
    servers = [d for d in Path("/proc").iterdir() if d.name.isdigit() and _ppid(d) == me
               and b"xmpp_server" in _read(d / "cmdline")]
    assert servers == []


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError:
        return b""


def _ppid(proc: Path) -> str:
    stat = _read(proc / "stat")
    return stat[stat.rfind(b")") + 2:].split()[1].decode() if stat else ""


async def test_replay_of_a_changed_rapp_names_its_first_divergence(recorded, tmp_path):
    out, _ = recorded
    changed = tmp_path / "changed"
    shutil.copytree(APP, changed)
    (changed / "manifest.yaml").write_text((changed / "manifest.yaml").read_text().replace("value: 21", "value: 22"))
    res = await replay(out, rapp_dir=changed, mode="inprocess", stall_s=20)
    d = res.divergence
    assert d is not None and d.kind == "different" and ".value" in d.text, res.summary()
    assert "double" in d.replay and '"value":22' in d.replay.replace(" ", "") and '"value":21' in d.recorded

    task = changed / "recorded_app" / "task.py"  # one request fewer: the recording's next is missing
    (changed / "manifest.yaml").write_text((changed / "manifest.yaml").read_text().replace("value: 22", "value: 21"))
    task.write_text(task.read_text().replace('        await self.robot.set_global_pose(x=pose.x, y=pose.y, theta=pose.theta)\n', ""))
    res = await replay(out, rapp_dir=changed, mode="inprocess", stall_s=20)
    d = res.divergence
    assert d is not None and d.kind == "unexpected" and "move_along_path" in d.replay and "set_global_pose" in d.recorded


async def test_rapp_replay_runs_the_recorded_package_sandboxed(recorded, tmp_path):
    out, _ = recorded
    res = await arapp("replay", out, timeout=180)
    assert res.returncode == 0 and "no divergence" in res.stdout, res.stdout + res.stderr
    res = await arapp("trace", "export", "--format", "mcap", out, "-o", tmp_path / "again.mcap", "--no-frames")
    assert res.returncode == 0, res.stderr
    channels = _channels(tmp_path / "again.mcap")
    assert "/nao/camera" not in channels and channels["/nao/path"][3] == 1


async def test_resimulation_matches_the_recording(recorded, tmp_path):
    """What is deterministic holds: the seed's world, the end, the reports; the path within a tolerance."""
    out, result = recorded
    again = await run_rapp(APP, "nao", "small", 3, None, tmp_path, timeout_s=240, command_at=result["command_sim_s"])
    assert again["ok"]
    c = resim.compare(out, tmp_path, "nao")
    assert c.ok, c.text()
    assert again["truth"]["doors"] == result["truth"]["doors"] and again["truth"]["lamps"] == result["truth"]["lamps"]
    assert [r["text"] for r in again["reports"]] == [r["text"] for r in result["reports"]]
    assert c.deviation_m < 0.1  # measured 0.003 m for this 0.3 m step
    other = json.loads((tmp_path / "result.json").read_text())  # a run of another seed is told apart
    other["seed"], other["truth"]["doors"] = 99, {"x": {"angle_deg": 1.0, "open": False}}
    (tmp_path / "result.json").write_text(json.dumps(other))
    c = resim.compare(out, tmp_path, "nao")
    assert not c.ok and any("seed" in d for d in c.differ) and any("doors" in d for d in c.differ)


@pytest.mark.parametrize("delivery, speak, listen, scenario", [("speech", True, False, None),
                                                            ("listen", False, True, "speech.yaml"),
                                                            ("chat", False, False, None)])
def test_a_re_simulation_gives_the_command_as_it_was_given(tmp_path, monkeypatch, delivery, speak, listen, scenario):
    """Said aloud, or by voice to a listening robot (its scenario's speech lines): so again, not typed."""
    from scenarios import run_rapp as R

    kept = {}

    class Began(Exception):
        pass

    async def fake_run(*args, **kw):  # the run itself is not this test's subject
        kept.update(kw)
        raise Began

    monkeypatch.setattr(R, "run_rapp", fake_run)
    rec = tmp_path / "rec"
    rec.mkdir()
    if scenario:
        (tmp_path / scenario).write_text("speech:\n  - {at: 1.0, say: double it}\n")
    (rec / "result.json").write_text(json.dumps({"robot": "nao", "house": "small", "seed": 3, "command": "double it",
                                                 "delivery": delivery, "command_sim_s": 2.0,
                                                 "scenario": str(tmp_path / scenario) if scenario else None}))
    with pytest.raises(Began):
        R.main([str(APP), "--replay", str(rec), "--out", str(tmp_path / "out"), "--quiet"])
    assert (kept["speak"], kept["listen"], kept["command_at"]) == (speak, listen, 2.0)


def test_a_voice_command_given_by_rapp_say_cannot_be_re_simulated(tmp_path, capsys):
    from scenarios.run_rapp import main

    (tmp_path / "result.json").write_text(json.dumps({"robot": "nao", "house": "small", "seed": 3, "command": None,
                                                      "delivery": "listen", "scenario": None}))
    assert main([str(APP), "--replay", str(tmp_path), "--quiet"]) == 2
    assert "rapp say" in capsys.readouterr().err


def test_the_trace_page_shows_the_scene_at_the_record_clicked(recorded, browser_page, tmp_path):
    """Item 5: clicking a message moves the scene to its time: the robot where it was then, the path
    it was following, the latest frame; the slider scrubs through the run."""
    from scenarios.trace_html import render_html, scene_data

    out, _ = recorded
    scene = scene_data(out)
    records = _trace(out)
    page = tmp_path / "trace.html"
    page.write_text(render_html(records, title="recorded", scene=scene), encoding="utf-8")
    browser_page.goto(page.as_uri())
    browser_page.wait_for_selector("#robot-pose")
    assert browser_page.is_visible("#scene") and browser_page.is_visible("#map-image")
    [path_t] = [p[0] for p in scene["robots"]["nao"]["paths"]]
    frame_t = scene["frames"][0][0]
    poses = scene["robots"]["nao"]["poses"]

    def click(action: str, performative: str = "request") -> float:
        rec = next(r for r in records if r["kind"] == "message" and r["action"] == action
                   and r["performative"] == performative and r["dir"] == "send")
        browser_page.locator(f'g.msg[data-conv="{rec["conversation_id"]}"][data-performative="{performative}"]').first.click()
        return rec["t"]

    t = click("get_global_pose")  # before the step: at the start, no path yet, no frame yet
    assert float(browser_page.get_attribute("#scene-time", "data-t")) == pytest.approx(t)
    start_x = float(browser_page.get_attribute("#robot-pose", "data-x"))
    assert start_x == pytest.approx(poses[0][1], abs=0.02)
    assert browser_page.locator("#scene-svg .plan").count() == 0
    assert browser_page.get_attribute("#camera-frame", "data-t") == ""

    t = click("report")  # after it: moved by its step, the path drawn, the frame shown
    assert t > path_t and t > frame_t
    assert float(browser_page.get_attribute("#robot-pose", "data-x")) == pytest.approx(start_x + 0.3, abs=0.08)
    assert browser_page.locator("#scene-svg .plan").count() == 1
    assert float(browser_page.get_attribute("#camera-frame", "data-t")) == pytest.approx(frame_t)
    assert browser_page.evaluate("document.getElementById('camera-frame').naturalWidth") > 0

    browser_page.fill("#scrub", "0")  # the slider to the start
    browser_page.dispatch_event("#scrub", "input")
    assert float(browser_page.get_attribute("#robot-pose", "data-x")) == pytest.approx(poses[0][1], abs=0.02)
    assert browser_page.problems == []
