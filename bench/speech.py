"""Spoken commands, end to end: the owner speaks in the simulated house (eSpeak NG voices and speeds,
0.5-3 m from the NAO, quiet / TV at 50 / 60 dB SPL at 1 m, 2.6 m from the robot), the Core hears
it through its microphone (voice activity detection), spots an isolated keyword itself (s4a) or has
the Platform recognise the sentence (s4b), and starts the RApp.

Measured per command: right RApp or not, and latency from the end of speech (simulation time reached
at rtf 1) to the Core's decision (s5 entered) and to the hand-off (the RApp started; Dynamic Agents
in-process, so the time is the Core's and not a Python process start, see the handoff benchmark).
The RApps are stand-ins with the reference RApps' keywords and phrases (read from their manifests)
that finish at once."""
from __future__ import annotations

import asyncio
import itertools
import shutil
import time
from pathlib import Path

from .common import log, metric, percentile

REFERENCE_RAPPS = ("hazard_detection", "weather_reporter", "email_reader", "cognitive_game")
RAPPS_DIR = Path(__file__).resolve().parent.parent / "rapps"


def reference_vocabulary(root: Path = RAPPS_DIR) -> dict[str, tuple[list[str], list[str]]]:
    """The reference RApps' keywords and phrases, as their manifests (rapps/*/manifest.yaml) have them."""
    import yaml

    out = {}
    for name in REFERENCE_RAPPS:
        manifest = yaml.safe_load((root / name / "manifest.yaml").read_text())
        out[name] = (list(manifest.get("keywords") or []), list(manifest.get("phrases") or []))
    return out


VOCABULARY = reference_vocabulary()
VOICES = ("en-us", "en-us+f3", "en-us+m3", "en", "en+f2")
SPEEDS = (130, 160, 190)
DISTANCES = (0.5, 1.0, 2.0, 3.0)
NOISE = {"quiet": None, "tv50": 50.0, "tv60": 60.0}
ROBOT_AT = (0.6, 0.6)
TV_AT = (3.2, 0.5, 0.8)

TASK = '''from rapps.sdk import FSM, Step, Task


class Done(Task):
    def build(self):
        fsm = FSM("done", initial="end")
        fsm.add_state("end", Step(self.end), final=True)
        return fsm

    async def end(self, memory):
        return None
'''


def write_stand_ins(root: Path) -> list[Path]:
    out = []
    for name, (keywords, phrases) in VOCABULARY.items():
        d = root / name
        (d / f"{name}_standin").mkdir(parents=True, exist_ok=True)
        (d / f"{name}_standin" / "__init__.py").write_text("")
        (d / f"{name}_standin" / "task.py").write_text(TASK)
        (d / "manifest.yaml").write_text(
            f"name: {name}\nversion: 1.0.0\ndescription: speech benchmark stand-in\nrobot_types: [nao]\n"
            f"keywords: [{', '.join(keywords)}]\nphrases:\n" + "".join(f"  - {p}\n" for p in phrases)
            + f"entry_point: {name}_standin.task:Done\nservices: []\nrobot_api: [communication]\n"
              "time_limit_s: 30\nauthor: bench\n")
        out.append(d)
    return out


def commands(path: str, n: int, seed: int) -> list[tuple[str, str, str, int, float]]:
    """n commands of one path: (text, rapp, voice, speed, distance), conditions cycled."""
    items = [(w if path == "keyword" else p, rapp) for rapp, (ws, ps) in VOCABULARY.items()
             for w, p in itertools.zip_longest(ws, ps) if (w if path == "keyword" else p)]
    out = []
    for i in range(n):
        text, rapp = items[(i * 5 + seed) % len(items)]
        out.append((text, rapp, VOICES[i % len(VOICES)], SPEEDS[(i // 2) % len(SPEEDS)],
                    DISTANCES[(i + seed) % len(DISTANCES)]))
    return out


async def run(quick: bool, per_condition: int | None = None, noises: list[str] | None = None) -> list[dict]:
    import tempfile

    from hearing import tts
    from robots import RobotAPI, World
    from robots.sound import NoiseSource, house_sound, talker_at
    from scenarios.system import RappSystem, wait_until

    from .common import quiet_logs

    quiet_logs()
    n = per_condition or (3 if quick else 10)
    noises = noises or list(NOISE)
    work = Path(tempfile.mkdtemp(prefix="bench-speech-"))
    world = await asyncio.to_thread(World.from_file, "small", seed=5, rtf=1.0)
    results: list[dict] = []
    try:
        async with RappSystem(work) as system:
            for app in write_stand_ins(work / "apps"):
                await system.publish(app)
            nao = await asyncio.to_thread(world.add_robot, "nao", None, (*ROBOT_AT, 0.0))
            api = RobotAPI(nao)
            handle = await system.add_robot("nao", api=api, dynamic_mode="inprocess")
            core = handle.core
            fsm = core.supervisor.behaviour

            def idle() -> bool:
                return (core.listening and core.dynamic is None and not core.speaking()
                        and "audio-listener" in core.active_behaviours())

            await wait_until(lambda: len(core.vocabulary) >= 9 and idle(), 60, "the Core listening")
            house = house_sound(world)
            mic_z = api.audio_in.position()[2]
            for noise in noises:
                house.remove("tv")
                if NOISE[noise]:
                    house.add(NoiseSource("tv", TV_AT, kind="tv", level_db=NOISE[noise], seed=5, start=world.time))
                # the listener learns the room's new sound: a TV switched on is first one sound too long for a
                # command (answered so), then the noise that speech is told from
                await asyncio.sleep(7.0 if NOISE[noise] else 1.5)
                for path in ("keyword", "platform"):
                    for text, rapp, voice, speed, dist in commands(path, n, seed=len(results)):
                        await wait_until(idle, 30, "the Core listening")
                        pcm = await asyncio.to_thread(tts.synthesize, text, voice, speed)
                        at = world.time + 0.3
                        house.play(f"owner-{at:.3f}", talker_at(ROBOT_AT, dist, mic_z), pcm, at=at, level_db=60)
                        row = await _one(core, world, fsm, at + len(pcm) / 16000 + dist / 343.0, idle)
                        row.update(noise=noise, path=path, text=text, expected=rapp, voice=voice, speed=speed,
                                   distance=dist, right=row.get("rapp") == rapp)
                        results.append(row)
                        log(f"speech {noise} {path} {text!r} {voice} {speed} {dist} m -> {row.get('rapp')} "
                            f"({row.get('branch')}) {row.get('decided_ms', float('nan')):.0f} ms")
            house.remove("tv")
    finally:
        world.close()
        shutil.rmtree(work, ignore_errors=True)
    return summarise(results)


async def _one(core, world, fsm, t_end: float, idle) -> dict:
    """Watch one command: wall time when the speech ended, s4 branch, decision, hand-off."""
    row: dict = {}
    start_hist = len(fsm.history)
    spoken = len(core.told)
    deadline = time.perf_counter() + 25.0
    wall_end = None
    while time.perf_counter() < deadline:
        now = time.perf_counter()
        if wall_end is None and world.time >= t_end:
            wall_end = now
        states = fsm.history[start_hist:]
        if "s5_download" in states and "decided_ms" not in row and wall_end is not None:
            row["decided_ms"] = (now - wall_end) * 1e3
            row["rapp"] = core.memory.get("rapp")
            row["branch"] = "s4b" if "s4b_platform" in states else "s4a"
        if "rapp" in row and "s8_serve" in states and "started_ms" not in row:  # handed over
            row["started_ms"] = (now - wall_end) * 1e3
        if any(t.startswith("Sorry") for t in core.told[spoken:]):
            row["sorry"] = True
            break
        if "started_ms" in row or ("rapp" in row and idle()):
            break
        await asyncio.sleep(0.005)
    return row


def summarise(rows: list[dict]) -> list[dict]:
    out = []
    for path in ("keyword", "platform"):
        mine = [r for r in rows if r["path"] == path]
        for noise in NOISE:
            cell = [r for r in mine if r["noise"] == noise]
            if cell:
                acc = 100.0 * sum(r["right"] for r in cell) / len(cell)
                out.append(metric(f"speech_{path}_accuracy_{noise}", acc, "%", None, None, len(cell),
                                  wrong=[f"{r['text']}|{r['voice']}|{r['speed']}|{r['distance']}->{r.get('rapp')}"
                                         for r in cell if not r["right"]][:10]))
                # a miss is "not understood" (the owner is asked again); a wrong RApp started is worse
                out.append(metric(f"speech_{path}_wrong_rapp_{noise}", sum(1 for r in cell if r.get("rapp")
                                  and not r["right"]), "commands", None, None, len(cell)))
        for what in ("decided", "started"):
            xs = [r[f"{what}_ms"] for r in mine if r["right"] and f"{what}_ms" in r]
            if xs:
                out.append(metric(f"speech_{path}_{what}", percentile(xs, 50), "ms", None, None, len(xs),
                                  samples=xs, meaning=f"end of speech -> {what} (median; right commands)"))
        branches = [r.get("branch") for r in mine if r["right"]]
        if branches:
            out.append(metric(f"speech_{path}_on_robot", 100.0 * branches.count("s4a") / len(branches), "%",
                              None, None, len(branches), meaning="right commands decided by s4a (keyword)"))
    return out
