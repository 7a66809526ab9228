"""A spoken "stop" during a task: the Core keeps spotting its supervision words on the microphone while
a RApp runs (and captures the same microphone itself); the owner's "stop", said in the house, latches
the owner's emergency stop and the task pauses, as the chat "stop" does."""
from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from agents.tracing import read_trace
from hearing import tts
from robots import RobotAPI, World
from robots.sound import house_sound, talker_at
from scenarios.system import RappSystem

from .test_lifecycle import wait_until

NAO_AT = (0.6, 0.6)

# a RApp that records the microphone in 0.2 s pieces until its task is paused, then says what it heard
TASK = '''import asyncio, base64, io, math, wave

from rapps.sdk import FSM, Step, Task


class Listen(Task):
    def build(self):
        fsm = FSM("listen", initial="listen")
        fsm.add_state("listen", Step(self.listen), final=True)
        return fsm

    async def listen(self, memory):
        chunks, loudest = 0, -120.0
        end = asyncio.get_running_loop().time() + 40.0
        await self.report("listening")
        while self.paused is None and asyncio.get_running_loop().time() < end:
            audio = await self.robot.capture_audio(seconds=0.2)
            with wave.open(io.BytesIO(base64.b64decode(audio.data_b64))) as w:
                raw = w.readframes(w.getnframes())
            samples = [int.from_bytes(raw[i:i + 2], "little", signed=True) for i in range(0, len(raw), 2)]
            rms = math.sqrt(sum(s * s for s in samples) / max(len(samples), 1))
            loudest = max(loudest, 20 * math.log10(rms / 32768 + 1e-12))
            chunks += 1
        await self.report(f"captured {chunks} chunks, loudest {loudest:.0f} dBFS, paused: {self.paused}")
        await self.wait_resumed()  # held until the owner resumes or cancels
'''


def write_rapp(root: Path) -> Path:
    d = root / "mic_listener"
    (d / "mic_listener").mkdir(parents=True)
    (d / "mic_listener" / "__init__.py").write_text("")
    (d / "mic_listener" / "task.py").write_text(TASK)
    (d / "manifest.yaml").write_text(
        "name: mic-listener\nversion: 1.0.0\ndescription: records the microphone until paused\n"
        "robot_types: [nao]\nkeywords: [microphone]\nphrases: []\nentry_point: mic_listener.task:Listen\n"
        "services: []\nrobot_api: [communication]\ntime_limit_s: 60\nauthor: tests\n")
    return d


def spotted_words(system) -> list:
    return [r.get("word") for r in read_trace(system.settings.trace_file)
            if r["kind"] == "structure" and r["event"] == "supervision-spotting"]


@pytest.mark.slow  # ~10 s: a real-time world (the owner speaks while the RApp and the Core listen)
async def test_a_spoken_stop_pauses_the_running_task(tmp_path):
    world = World.from_file("small", seed=4, rtf=1.0)  # real time: the owner speaks while the robot listens
    try:
        async with RappSystem(tmp_path, trace_file=tmp_path / "trace.jsonl") as system:
            await system.publish(write_rapp(tmp_path / "apps"))
            nao = world.add_robot("nao", pose=(*NAO_AT, 0.0))
            api = RobotAPI(nao)
            handle = await system.add_robot("nao", api=api, dynamic_mode="inprocess", voice_supervision=True)
            core, user = handle.core, handle.user
            await wait_until(lambda: core.vocabulary and core.listening, 60)
            start = len(user.received)
            await user.say(core.address, "microphone")  # the task starts by chat; the owner then speaks
            await user.wait_for(lambda t: t.endswith("] listening"), timeout=30, start=start)  # the RApp's, labelled
            assert core.robot_commands.estop_reason is None and core.dynamic is not None
            await wait_until(lambda: not core.hearing.robot_talking(), 10)  # "Starting ..." is chat only; be sure

            pcm = tts.synthesize("stop", "en-us")
            at = world.time + 0.3
            house_sound(world).play("owner-stop", talker_at(NAO_AT, 1.0, api.audio_in.position()[2]), pcm,
                                    at=at, level_db=60)
            try:
                reply = await user.wait_for(lambda t: t.startswith("captured"), timeout=30, start=start)
            except asyncio.TimeoutError:
                raise AssertionError(f"not stopped; the Core spotted: {spotted_words(system)}") from None

            # the same effect as the chat "stop": the owner's emergency stop, the task paused, not ended
            assert core.robot_commands.estop_reason == "stopped by the user" and core.robot_commands.estop_by == "owner"
            assert core.dynamic is not None and not core.dynamic.ended.is_set()
            assert "paused: stopped by the user" in reply
            # the RApp recorded the same microphone meanwhile: the owner's word is in its samples too
            loudest = float(reply.split("loudest ")[1].split(" dBFS")[0])
            assert loudest > -55, reply  # the microphone's own noise alone is near -70 dBFS
            assert "stop" in spotted_words(system)

            await user.say(core.address, "cancel")  # ends the paused task; the Core supervises again
            await wait_until(lambda: core.dynamic is None and core.listening, 30)
            assert core.hearing.task_stream is None
    finally:
        world.close()
