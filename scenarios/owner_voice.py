"""The owner's voice in a simulated run: spoken lines from the command line (`rapp say TEXT`), from a
scenario file (`speech:` lines with a time) or as the run's first command (`rapp run rapp ... --speak`).

A line is synthesised by eSpeak NG (hearing/tts.py, the `speech` extra) and played into the house's
sound (robots/sound.py) where the owner stands: `distance` m from the robot's microphone, at the
robot's position when the line starts. The robot hears it only through its microphone, as a real
one would (distance, walls, the TV). `rapp say` reaches a running `rapp run` through the run's inbox
folder: it drops one file per line there, the run plays each file and removes it. The running run
is found through a pointer file (`current_run_file()`: the run's folder and process id).
"""
from __future__ import annotations

import asyncio
import json
import os
import time
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from robots.scenario_file import read_section

INBOX = "inbox"
RUN_PID = ".pid"  # in the inbox: the process serving it (a finished run's folder keeps its inbox)
POLL_S = 0.2  # how often the run looks into its inbox (wall clock)
DEFAULT_VOICE = "en-us"


class SpokenLine(BaseModel):
    """One thing the owner says: at simulation time `at` s (scripted) or as soon as it arrives."""

    model_config = ConfigDict(extra="forbid")
    say: str = Field(min_length=1, max_length=500)
    at: float = Field(default=0.0, ge=0.0)
    voice: str = DEFAULT_VOICE
    speed: int = Field(default=150, ge=80, le=450, description="words per minute")
    distance: float = Field(default=1.0, ge=0.3, le=8.0, description="metres from the robot's microphone")
    level_db: float = Field(default=60.0, ge=30.0, le=90.0, description="dB SPL at 1 m (conversation: 60)")


class ScriptError(ValueError):
    pass


def load_script(path: str | Path) -> list[SpokenLine]:
    """The `speech:` lines of a scenario file (YAML; other keys belong to other parts of the run)."""
    path = Path(path)
    lines = read_section(path, "speech", ScriptError)
    out = []
    for i, line in enumerate(lines):
        try:
            out.append(SpokenLine.model_validate(line))
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(str(p) for p in first["loc"])
            raise ScriptError(f"scenario file {path}: speech[{i}]{'.' + where if where else ''}: {first['msg']}") from None
    return sorted(out, key=lambda s: s.at)


# ------------------------------------------------------------------------------------- rapp say
def current_run_file() -> Path:
    base = os.environ.get("XDG_RUNTIME_DIR") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "rapp" / "current-run.json"


def announce_run(out: Path) -> Path:
    """Make this run the one `rapp say` talks to (the newest run wins)."""
    pointer = current_run_file()
    pointer.parent.mkdir(parents=True, exist_ok=True)
    tmp = pointer.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps({"out": str(out.resolve()), "pid": os.getpid()}))
    tmp.replace(pointer)
    return pointer


def retire_run(out: Path) -> None:
    pointer = current_run_file()
    try:
        if json.loads(pointer.read_text()).get("out") == str(out.resolve()):
            pointer.unlink()
    except (OSError, ValueError):
        pass


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def running_inbox(run: str | Path | None = None) -> Path:
    """The inbox of the run `rapp say` speaks into: `run` (its --out folder) or the current one."""
    if run is not None:
        inbox = Path(run) / INBOX
        if not inbox.is_dir():
            raise ScriptError(f"{run} is not a running `rapp run` folder (no {INBOX}/ in it)")
        try:
            pid = int((inbox / RUN_PID).read_text())
        except (OSError, ValueError):
            pid = None  # a run from before the pid was kept: trusted
        if pid is not None and not _alive(pid):
            raise ScriptError(f"the run in {run} (pid {pid}) has ended; start a new one")
        return inbox
    pointer = current_run_file()
    try:
        info = json.loads(pointer.read_text())
    except (OSError, ValueError):
        raise ScriptError("no `rapp run` is running here: start one (e.g. `rapp run rapp rapps/examples/hello "
                          "--robot nao`), then `rapp say` while it runs") from None
    if not _alive(int(info.get("pid", 0))):
        raise ScriptError(f"the last `rapp run` (pid {info.get('pid')}) has ended; start a new one")
    return Path(info["out"]) / INBOX


def post_line(line: SpokenLine, run: str | Path | None = None) -> Path:
    """Drop one line into a running run's inbox (written whole, then renamed: never read half)."""
    inbox = running_inbox(run)
    name = f"{time.time_ns()}-{os.getpid()}"
    tmp = inbox / f".{name}.tmp"
    tmp.write_text(line.model_dump_json())
    final = inbox / f"{name}.json"
    tmp.replace(final)
    return final


# ------------------------------------------------------------------------------------- the run side
class OwnerVoice:
    """The owner speaking into a run's house: `speak` now, `run_script` at scripted times, `serve_inbox`
    for `rapp say`. `heard` lists what was played (simulation time, text) for the run's result."""

    def __init__(self, world, api, out: Path, log=print):
        self.world, self.api, self.log = world, api, log
        self.inbox = Path(out) / INBOX
        self.inbox.mkdir(parents=True, exist_ok=True)
        (self.inbox / RUN_PID).write_text(str(os.getpid()))
        self.spoken: list[dict] = []
        self.busy_until = 0.0  # one owner, one mouth: a line starts after the last one ended

    def check(self) -> None:
        """Fail early and clearly when the owner cannot be heard: no microphone, or no synthesiser."""
        if "microphone" not in self.api.capabilities():
            raise ScriptError(f"the {self.api.robot.kind} has no microphone: speak to it by chat (--say)")
        from hearing import tts
        from hearing.errors import SpeechUnavailable
        try:
            tts.data_path()
        except (ImportError, SpeechUnavailable):
            raise ScriptError("speaking needs eSpeak NG: pip install -e '.[speech]'") from None

    async def speak(self, line: SpokenLine) -> float:
        """Play `line` at the owner's place; returns the simulation time its last sample reaches the robot."""
        from hearing import tts
        from hearing.wav import SAMPLE_RATE
        from robots.sound import house_sound, talker_at

        pcm = await asyncio.to_thread(tts.synthesize, line.say, line.voice, line.speed)
        mic = self.api.audio_in.position()
        at = max(self.world.time + 0.1, self.busy_until + 0.4)
        mouth = talker_at(mic[:2], line.distance, mic[2])
        house_sound(self.world).play(f"owner-{at:.3f}", mouth, pcm, at=at, level_db=line.level_db)
        self.spoken.append({"t": round(at, 3), "say": line.say, "distance": line.distance})
        self.log(f"[owner] says aloud at simulated t={at:.1f} s, {line.distance:.1f} m away: {line.say!r}")
        self.busy_until = at + len(pcm) / SAMPLE_RATE
        return self.busy_until + line.distance / 343.0

    async def run_script(self, lines: list[SpokenLine]) -> None:
        for line in lines:
            while self.world.time < line.at:
                await self.world.sleep(min(0.5, line.at - self.world.time), drive=False)
            await self.speak(line)

    async def serve_inbox(self) -> None:
        """Play each line `rapp say` drops into the inbox, in arrival order; a bad file is reported and removed."""
        while True:
            for path in sorted(self.inbox.glob("*.json")):
                try:
                    line = SpokenLine.model_validate_json(path.read_text())
                except (OSError, ValidationError, ValueError) as exc:
                    self.log(f"[owner] ignored {path.name}: {str(exc).splitlines()[0]}")
                else:
                    try:
                        await self.speak(line)
                    except Exception as exc:  # noqa: BLE001 - a line that cannot be said must not end the run
                        self.log(f"[owner] could not say {line.say!r}: {exc}")
                path.unlink(missing_ok=True)
            await asyncio.sleep(POLL_S)
