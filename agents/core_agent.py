"""Core Agent: one per robot; owns its virtual effectors and receptors (a robots.api.RobotAPI),
talks to its user, and hands supervision to a Dynamic Agent and back (paper 000 sec. 5.1).

Behaviours and when they are active (see `active_behaviours()`):
  supervisor      always   the FSM of fig. 5 (agents/core_fsm.py)
  core-service    always   task status / heartbeats / reports of the current Dynamic Agent
  user-listener   while the Core supervises: user chat -> command queue
  microphone-listener  while the Core supervises: what the robot's microphone hears -> commands
  audio-listener  while the Core supervises: the microphone's sound, voice activity -> utterances
                  (s4 spots an isolated keyword itself, sends anything longer to the Platform)
  command-server  while a Dynamic Agent supervises: its robot-API requests (fig. 5, s8/s9)
  (the scheduler, a background task: the owner's schedules come due into the command queue,
                  agents/scheduler.py; kept in `data_dir`)
  busy-chat       while a Dynamic Agent supervises: answers the user, "stop" cancels the task
  heartbeats      while a Dynamic Agent supervises: its liveness (a hang is noticed within 2 s)
  (voice supervision, a background task, not a behaviour, with voice_supervision=True: while a RApp runs, the
                  microphone's sound is still spotted for "stop" / "cancel" / "resume", as the chat's)
  safety          while a Dynamic Agent supervises: an obstacle closer than `safety_distance`
                  latches the emergency stop (paper 003); nothing moves until "resume"
The listener, heartbeat and safety behaviours are in agents/core_behaviours.py.

The Core is composed of members, each built with a narrow interface of what it needs (the Protocols
of agents/core_parts.py), none importing the Core back:
  hearing         CoreHearing (agents/core_hearing.py): the microphone's sound, keyword spotting,
                  the supervision words during a task, the robot's own voice cut out
  robot_commands  RobotCommands (agents/core_commands.py): the command server, locks, the emergency
                  stop and the safety check's range readings
  events          CoreEvents (agents/core_events.py): sensor events to the supervising Dynamic Agent
  strategies      Strategies (agents/core_strategies.py): what a safety stop does before the hand-back
How it runs (trust, Dynamic Agents, hearing, safety, where it keeps things) is one CoreOptions.

Rights: robot commands are executed only for the current Dynamic Agent, only in the robot-API
groups its manifest declares, and each takes the lock of its device (agents/locks.py); see
agents/core_commands.py.
"""
from __future__ import annotations

import asyncio
import base64
import itertools
import logging
import re
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from spade.message import Message

import ontology.robot
from behaviours import BehaviourHost
from behaviours.pause import charged_seconds
from ontology import core as C
from ontology import platform as P
from ontology import store as S
from ontology.acl import Performative
from ontology.registry import Done
from ontology.spawn import RobotInfo, SpawnSpec
from robots.interface import check_robot
from ontology.package import Package, read_package, unpack_package
from ontology.errors import ErrorCode
from ontology.results import (RefusalRecord, ReportRecord, ScheduleChanged, SubscribeTasks, TaskEnded, TaskRecord,
                              TaskReported, TaskStage, TaskTrigger)
from ontology.services.interpretation import InterpretCommand, Interpretation, RAppDescription
from ontology.services.speech import SpeechRecognition
from hearing.keywords import keyword_in_a_sentence
from hearing.vad import HeardUtterance
from hearing.wav import encode_wav

from .base import RappAgent
from .core_behaviours import HeartbeatMonitor, MicrophoneListener, SafetyMonitor, UserChat, heartbeat_template
from .core_commands import RobotCommands
from .core_confirm import Confirmation
from .core_localizer import CoreLocalizer
from .core_hearing import CoreHearing
from .core_events import CoreEvents
from .core_parts import DynamicSession
from .core_strategies import Strategies
from .core_fsm import LISTEN, build_core_fsm
from .scheduler import ScheduledStart, Scheduler
from .errors import Refusal, RequestError, RequestFailed
from .messages import bare
from .identity import EphemeralAccounts, trace_refusal
from .liveness import GRACE_S, MARK_AFTER_S, SilenceWatch, sample_main_thread
from .process import (AgentProcess, Limits, check_spawn_mode, crash_summary, spawn_agent,
                      sweep_run_dirs)
from .sandbox import Sandbox
from .responder import Responder
from .warm_pool import WarmPool
from .store_client import download_package
from .tracing import keep_package

log = logging.getLogger("rapp.core")


def _words(text: str) -> list[str]:
    """A typed command's words, lower case (a single one may be a keyword)."""
    return re.findall(r"[\w'-]+", text.lower())
HEARTBEAT_TIMEOUT_S = 1.5  # a_dyn beats every 0.25 s: a hang is noticed within 2 s
STOP_WORDS = {"stop", "halt", "freeze", "emergency stop"}  # latch the emergency stop: the task pauses
CANCEL_WORDS = {"cancel", "abort"}  # end the running task (no task: as "stop")
RESUME_WORDS = {"resume", "continue", "go on"}
MAX_APOLOGIES_ALOUD = 2  # in a row, for heard sound not understood (CoreAgent.apology_aloud)
SUPERVISION_WORDS = {**{w: "stop" for w in STOP_WORDS}, **{w: "cancel" for w in CANCEL_WORDS},
                     **{w: "resume" for w in RESUME_WORDS}}  # heard by voice during a task too


__all__ = ["CoreAgent", "CoreOptions", "DynamicSession"]  # DynamicSession: agents/core_parts.py


@dataclass(frozen=True)
class CoreOptions:
    """How a Core runs, beside who it is and whom it talks to; every field has its default (a
    scenario passes the few it changes by name: CoreOptions(**core_kw))."""

    # packages: the keys a package may be signed with, and whether it must be
    trusted_keys: Any = None
    require_signature: bool = False
    # Dynamic Agents: how each runs (agents/process.py), its limits and sandbox, processes started ahead
    # (agents/warm_pool.py; 0: each starts cold) and the modules they import ahead
    dynamic_mode: str = "process"
    limits: Limits = Limits()
    sandbox: Sandbox | None = None
    warm_workers: int = 1
    warm_imports: tuple[str, ...] = ()
    # hearing and talking (agents/core_hearing.py): the microphone's sound, the supervision words
    # during a task, and the RApps' reports said aloud
    hear_audio: bool = True
    voice_supervision: bool = False
    say_reports: bool = True
    # safety (paper 003): the margin of the range sensors' check (None: off) and its period
    safety_distance: float | None = 0.10
    safety_period: float = 0.2
    # where it keeps things: its work directory (None: a temporary one, removed whole at stop) and what
    # survives a restart, the owner's schedules (None: in memory, for this run only); the schedules' clock
    workdir: str | Path | None = None
    data_dir: str | Path | None = None
    clock: Any = None


class CoreAgent(RappAgent):
    """The Core Agent: the FSM of fig. 5 (agents/core_fsm.py) calls its steps; its members (hearing,
    robot_commands, events, strategies) do the rest."""

    init_wait_s: float | None = None  # how long a Dynamic Agent may take to report Init (None: its login's + 10 s)

    def __init__(self, name: str, *, robot_id: str, robot_type: str, robot_api, owner: str,
                 platform: str, store: str, user: str, password: str, settings=None,
                 options: CoreOptions = CoreOptions()):
        super().__init__(name, settings)
        o = self.options = options
        self.accounts = EphemeralAccounts(self.settings, owner=name)
        self.sandbox = o.sandbox or Sandbox()
        self.robot_id, self.robot_type, self.robot = robot_id, robot_type, check_robot(robot_api)
        self.owner = self.settings.jid(owner)
        self.platform, self.store = self.settings.jid(platform), self.settings.jid(store)
        self.user, self.password = user, password
        self.token = ""
        self._own_workdir = o.workdir is None  # a temporary one: removed whole at stop
        self.workdir = Path(o.workdir or tempfile.mkdtemp(prefix=f"rapp-core-{robot_id}-"))
        self.trusted_keys, self.require_signature = o.trusted_keys, o.require_signature
        self.limits, self.say_reports = o.limits, o.say_reports
        self.memory: dict = {}
        self.vocabulary: dict[str, str] = {}
        self.catalogue: list[S.PackageSummary] = []
        self.commands: asyncio.Queue[str | HeardUtterance | ScheduledStart] = asyncio.Queue()
        self.dynamic: DynamicSession | None = None
        self.told: list[str] = []  # everything said to the user, in order
        self.last_refusals: list[dict] = []  # what the last RApp run was refused (told to the owner at its end)
        self.supervisor: BehaviourHost | None = None
        self._serial = itertools.count(1)
        self._background: set[asyncio.Task] = set()
        self._deletions: set[asyncio.Task] = set()  # ephemeral accounts being deleted
        self._speech: asyncio.Task | None = None  # the last utterance queued on the loudspeaker
        self.sentences_begun = 0  # sentences given to the loudspeaker so far (the listener drops sound meanwhile)
        self._heard_apologies = 0  # apologies in a row for heard sound not understood (see apology_aloud)
        check_spawn_mode(o.dynamic_mode, "dynamic_mode")
        self.dynamic_mode = o.dynamic_mode
        # one RApp at a time: the worker handed a run is the pool's until the run ends (no refill
        # waiting out the whole run beside it)
        self.warm_pool = WarmPool(self.workdir, self.settings, size=o.warm_workers, limits=o.limits,
                                  sandbox=self.sandbox, preload=o.warm_imports, hold_running=True)
        self.task_watchers: set[str] = set()  # the owner's clients told of reports and ends (ontology/results.py)
        self._command_told: tuple[str, int] | None = None  # the command in hand and len(told) when it came
        self.safety_period = o.safety_period
        # the members (agents/core_parts.py says what each needs of the Core)
        self.hearing = CoreHearing(self, SUPERVISION_WORDS, hear_audio=o.hear_audio,
                                   voice_supervision=o.voice_supervision)
        self.confirmation = Confirmation(self, self.hearing)  # a schedule heard by voice (agents/core_confirm.py)
        self.robot_commands = RobotCommands(self, self._publish, safety_distance=o.safety_distance)
        self.events = CoreEvents(self, self.robot_commands.nearest_echo)
        self.strategies = Strategies(self, self.robot_commands, self.events.publish_echo)
        self.robot_commands.on_safety_stop = self.strategies.react_to_obstacle
        self.data_dir = Path(o.data_dir) if o.data_dir else None
        self.scheduler = Scheduler(self, self.data_dir / "schedules.db" if self.data_dir else None, o.clock)
        self._trigger: ScheduledStart | None = None  # the schedule the command in hand came from
        self.localizer = CoreLocalizer(self.robot, robot_type)  # its own pose estimate (paper 001)
        self.robot_commands.localizer = self.localizer  # serves get_pose_estimate, add_pose_fix

    async def _publish(self, topic, ttl_s, **data):
        """RobotCommands' way to the events (built after it: they read the range sensors through it)."""
        return await self.events.publish(topic, ttl_s, **data)

    @property
    def listening(self) -> bool:
        """The Core waits for its owner's next command (fig. 5's s3)."""
        return self.supervisor is not None and self.supervisor.behaviour.current == LISTEN

    # -- setup and behaviours ------------------------------------------------------------
    async def setup(self) -> None:
        await asyncio.to_thread(sweep_run_dirs, self.workdir)  # what a crash left behind
        if self.dynamic_mode == "process":
            self.warm_pool.start()
        service = Responder(C.ONTOLOGY, {"task_status": self._on_status, "report": self._on_report,
                                         "get_state": self._on_get_state, "release_stop": self._on_release_stop})
        self.activate("core-service", service, service.make_template())
        events = self.events.service()  # FIPA subscribe to sensor events (agents/core_events.py)
        events.handlers[SubscribeTasks.action_name] = self._on_subscribe_tasks  # and to task records
        self.activate("core-events", events, events.make_template())
        self.activate("user-listener", UserChat(self.owner, self._command_heard))
        self._listen_to_microphone()
        self.supervisor = BehaviourHost(build_core_fsm(), self.memory)
        self.activate("supervisor", self.supervisor)
        self.scheduler.start()
        self.localizer.start()

    def _listen_to_microphone(self) -> None:
        mic = self.robot.microphone
        if mic is not None:
            self.activate("microphone-listener", MicrophoneListener(mic, self._command_heard))
        audio = self.hearing.audio_listener()
        if audio is not None:
            self.activate("audio-listener", audio)

    async def heard_command(self, utterance: HeardUtterance) -> None:
        """An utterance the Core's hearing took as a command (in s3)."""
        await self.commands.put(utterance)

    async def heard_supervision_word(self, word: str) -> None:
        """A supervision word heard during a task: as the owner's chat "stop" / "cancel" / "resume"."""
        if self.dynamic is not None:
            await self._busy_chat(word)

    async def on_reconnected(self) -> None:
        """The running task is told its pause state again (RobotCommands.retell_task)."""
        if self.dynamic is not None:
            await self.robot_commands.retell_task()

    def speaking(self) -> bool:
        """The robot's loudspeaker is busy with the Core's own sentences."""
        return self._speech is not None and not self._speech.done()

    async def _command_heard(self, text: str) -> None:
        self.record_structure("command", text=text[:200])
        word = text.lower().strip(" .!")
        if word not in STOP_WORDS | CANCEL_WORDS and self.confirmation.take_typed(text):
            return  # "yes" / "no" to the question waiting (s4c); a stop word stays a stop
        if word in STOP_WORDS | CANCEL_WORDS:
            await self.robot_commands.emergency_stop("stopped by the user")
        elif word in RESUME_WORDS:
            await self.robot_commands.resume_motion()
        else:
            await self.commands.put(text)

    async def next_command(self) -> str | HeardUtterance:
        await self._command_failed()  # back in s3 without a task's end: the last command failed before it ran
        command = await self.commands.get()
        for key in ("rapp", "params", "package", "schedule", "missed"):  # the last command's, not this one's
            self.memory.pop(key, None)
        self._trigger = command if isinstance(command, ScheduledStart) else None
        text = command.schedule.command if self._trigger else command if isinstance(command, str) else ""
        self._command_told = (text, len(self.told))
        return command

    def command_answered(self) -> None:
        """The command in hand was answered without a task (a schedule kept, cancelled or listed)."""
        self._command_told = None

    def hear(self, text: str) -> None:
        """The robot's microphone heard the user (scenario scripts and tests call this)."""
        self.commands.put_nowait(text)

    # -- s1, s2 ------------------------------------------------------------------------
    async def register_everywhere(self) -> None:
        try:
            await self.request(self.platform, P.RegisterUser(user=self.user, password=self.password))
        except RequestError as e:
            if e.code != ErrorCode.DUPLICATE:
                raise
        await self._login()
        await self.request(self.platform, P.RegisterRobot(robot_id=self.robot_id, robot_type=self.robot_type,
                                                          core_jid=self.address))
        await self.request(self.store, S.RegisterOwner(owner=self.user, password=self.password))
        await self.request(self.store, S.RegisterRobot(robot_id=self.robot_id, robot_type=self.robot_type,
                                                       owner=self.user, token=self.token))
        self.record_structure("register", robot=self.robot_id, platform=self.platform, store=self.store)
        self.in_background(self._sweep_accounts(self.accounts.pending()))

    async def _sweep_accounts(self, leftovers: dict[str, str]) -> None:
        """Delete the ephemeral accounts a crashed earlier run of this Core left behind."""
        gone = await self.accounts.sweep(leftovers)
        if gone:
            self.record_structure("accounts-swept", accounts=gone)

    async def _login(self) -> None:
        login = await self.request(self.platform, P.Login(user=self.user, password=self.password,
                                                          ttl_s=24 * 3600))
        self.token, self.token_expires = login.token, login.expires_at

    async def fresh_token(self) -> str:
        """The Core's token, renewed when it has less than an hour left."""
        if time.time() > getattr(self, "token_expires", 0) - 3600:
            await self._login()
        return self.token

    def set_catalogue(self, packages: list[S.PackageSummary]) -> None:
        self.catalogue = list(packages)
        self.vocabulary = {kw.lower(): p.name for p in packages for kw in p.keywords}
        self.hearing.set_vocabulary(self.vocabulary, [ph for p in packages for ph in p.phrases])
        self.record_structure("vocabulary", rapps=[p.name for p in packages],
                              keywords=sorted(self.vocabulary))

    # -- s4 ------------------------------------------------------------------------------
    async def refresh_catalogue(self) -> None:
        reply = await self.request(self.store, S.ListPackages(robot_type=self.robot_type))
        self.set_catalogue(reply.packages)

    async def subscribe_catalogue(self) -> None:
        """FIPA subscribe: the Store tells this Core of every publish and removal."""
        await self.request(self.store, S.SubscribeCatalogue(robot_type=self.robot_type),
                           performative=Performative.SUBSCRIBE)

    async def on_unhandled(self, msg, info) -> None:
        if (info.ontology, info.action) == (S.ONTOLOGY, "catalogue_changed") and bare(msg.sender) == self.store:
            self.record_structure("catalogue-changed", content=(msg.body or "")[:200])
            self.in_background(self.refresh_catalogue())
            return
        await super().on_unhandled(msg, info)

    async def interpret(self, text: str) -> Interpretation:
        words = _words(text)
        if len(words) == 1 and words[0] not in self.vocabulary or not self.catalogue:
            await self.refresh_catalogue()  # a RApp published since s2
        if len(words) == 1 and words[0] in self.vocabulary:
            return Interpretation(rapp=self.vocabulary[words[0]], score=1.0, matched=words)
        if not self.catalogue:
            raise RequestFailed(f"no application for a {self.robot_type} robot is in the Store", code=ErrorCode.NO_RAPPS)
        rapps = [RAppDescription(name=p.name, keywords=p.keywords, phrases=p.phrases, robot_types=p.robot_types)
                 for p in self.catalogue]
        return await self.request(self.platform, InterpretCommand(token=await self.fresh_token(), text=text,
                                                                  robot_type=self.robot_type, rapps=rapps))

    def keyword_rapp(self, text: str) -> str | None:
        """s4a for typed commands: the RApp of a single known keyword, else None."""
        words = _words(text)
        return self.vocabulary.get(words[0]) if len(words) == 1 else None

    async def spot_keyword(self, utterance: HeardUtterance) -> str | None:
        """s4a for speech: the RApp of an isolated keyword (pocketsphinx on this robot), else None."""
        word = await self.hearing.spot(utterance)
        return self.vocabulary.get(word.lower()) if word else None

    async def recognise_sentence(self, utterance: HeardUtterance) -> str:
        """s4b for speech: the Platform's `recognition`, a sentence the owner paused in recognised whole
        (CoreHearing.recognise_sentence)."""
        return await self.hearing.recognise_sentence(utterance, self.recognition)

    async def recognition(self, utterance: HeardUtterance) -> tuple[str, str]:
        """The Platform's speech_recognition of one utterance, first against the Store's command phrases
        and keywords (each may end with a time: a schedule), then with the general language model:
        (text, the search that heard it); "" when neither heard anything."""
        wav = await asyncio.to_thread(lambda: base64.b64encode(encode_wav(utterance.pcm)).decode())
        sentences = sorted({ph for p in self.catalogue for ph in p.phrases} | set(self.vocabulary))
        for allowed in (sentences, []):
            try:
                # times: a Store sentence said with a time is a schedule's (paper 000 sec. 7's trigger)
                reply = await self.request(self.platform, SpeechRecognition(
                    token=await self.fresh_token(), audio_b64=wav, sentences=allowed, times=bool(allowed)), timeout=15.0)
            except RequestError as e:
                if not allowed or e.code != ErrorCode.UNSUPPORTED:
                    raise  # the recording itself was refused (silent, clipped): the model would refuse it too
                # no phrase it can pronounce (a Platform without eSpeak NG): the general model may still hear it
                log.warning("speech recognition refused the Store's phrases: %s", e.reason)
                self.record_structure("speech-recognition", text="", search="sentences", error=e.reason)
                continue
            # a bare keyword heard in a longer utterance: the general model hears the sentence whole
            part = bool(allowed) and keyword_in_a_sentence(reply, self.hearing.keywords.keywords, utterance)
            self.record_structure("speech-recognition", text=reply.text, search=reply.search,
                                  confidence=reply.confidence, **({"keyword_alone": False} if part else {}))
            if reply.text.strip() and not part:
                return reply.text.strip(), reply.search
        return "", ""

    # -- s5 ------------------------------------------------------------------------------
    def apology_aloud(self) -> bool:
        """Whether an apology for heard sound not understood is said aloud (it always reaches the chat):
        the first MAX_APOLOGIES_ALOUD in a row are, until a command is understood again. The microphone
        hears all the house's sound, other robots' voices too: two idle Cores in one room otherwise
        answered each other's "Sorry, I did not understand" without end."""
        self._heard_apologies += 1
        return self._heard_apologies <= MAX_APOLOGIES_ALOUD

    async def fetch_package(self, rapp: str) -> tuple[Package, bytes]:
        self._heard_apologies = 0  # a command was understood (s5)
        # the version the Store lists for this robot type (its build for the type passed), not the latest
        version = next((p.version for p in self.catalogue if p.name == rapp), None)
        info, data = await download_package(self, self.store, rapp, version, token=await self.fresh_token())
        package = await asyncio.to_thread(read_package, data, trusted_keys=self.trusted_keys,
                                          require_signature=self.require_signature)
        if self.robot_type not in package.manifest.robot_types:
            raise RuntimeError(f"{rapp} {package.manifest.version} does not support a {self.robot_type} robot")
        keep_package(self.tracer, data)  # a recorded run keeps it beside its trace (rapp replay)
        self.record_structure("download", rapp=rapp, version=info.version, size=info.size,
                              sha256=info.sha256, signature=package.signature.value)
        return package, data

    # -- s6: spawn and hand over ----------------------------------------------------------
    async def start_dynamic(self, package_and_bytes, params: dict) -> None:
        package, data = package_and_bytes
        m = package.manifest
        n = next(self._serial)
        workdir = self.workdir / f"{n:04d}-{m.name}"
        await asyncio.to_thread(unpack_package, data, workdir / "package", trusted_keys=self.trusted_keys,
                                require_signature=self.require_signature)
        ident = self.accounts.take(self._dynamic_prefix(m.name))  # made ahead, or registered at its login
        session = DynamicSession(jid=self.settings.jid(ident.name), rapp=m.name, version=m.version,
                                 manifest=m, workdir=workdir, account=ident,
                                 command=self._command_told[0] if self._command_told else "",
                                 trigger=TaskTrigger.SCHEDULED if self._trigger else TaskTrigger.COMMAND,
                                 schedule_id=self._trigger.schedule.id if self._trigger else None)
        self.dynamic = session
        try:
            await self._spawn(session, ident, params)
        except Exception as e:  # the owner is told why once, by s10 (destroy_dynamic), from the session
            self._end(session, str(e) or type(e).__name__)
            raise
        self._handoff()
        self.accounts.prepare(self._dynamic_prefix(m.name))  # the next run of this RApp only logs in

    async def _spawn(self, session: DynamicSession, ident, params: dict) -> None:
        """s6 after the unpack: the run's token, the process, and its Init."""
        m, name = session.manifest, ident.name
        app_token = await self.request(self.platform, P.IssueAppToken(
            token=await self.fresh_token(), rapp=m.name, services=m.services, holder_jid=session.jid,
            ttl_s=max(60.0, m.time_limit_s + 60)))
        spec = SpawnSpec(kind="dynamic", name=name, password=ident.password, package_dir="",
                         core=self.address, platform=self.platform, token=app_token.token, params=params,
                         robot=RobotInfo(robot_id=self.robot_id, robot_type=self.robot_type,
                                         capabilities=sorted(self.robot.capabilities())),
                         record=self.tracer.bodies is not None)
        session.process = spawn_agent(spec, session.workdir, self.settings, mode=self.dynamic_mode, limits=self.limits,
                                      sandbox=self.sandbox, pool=self.warm_pool)
        session.process.on_refusal = lambda refusal: self._sandbox_refused(session, refusal)
        await session.process.start()
        self.record_structure("spawn", dynamic=session.jid, rapp=m.name, version=m.version,
                              pid=session.process.pid, sandbox=session.process.sandboxed,
                              warm=getattr(session.process, "warm", False),
                              params=params, robot=spec.robot.model_dump())  # what a replay gives its run
        watcher = asyncio.create_task(self._watch_process(session))
        wait = self.init_wait_s if self.init_wait_s is not None else self.settings.start_timeout + 10
        try:
            await asyncio.wait_for(session.ready.wait(), wait)
        except asyncio.TimeoutError:
            words = session.process.stderr_tail(500).strip()
            raise RuntimeError(f"it did not report Init within {wait:g} s (its import or build takes longer, or "
                               f"hangs){': ' + words if words else ''}") from None
        if session.ended.is_set():
            raise RuntimeError(session.end_reason or "it ended at start")
        del watcher

    async def stop(self) -> None:
        await self.scheduler.stop()
        await self.localizer.stop()
        for task in list(self._background):
            task.cancel()
        await self.warm_pool.close()  # idle workers killed and reaped
        if self._deletions:
            await asyncio.wait(list(self._deletions), timeout=5.0)
        if self.dynamic is not None and self.dynamic.process is not None:
            await self.dynamic.process.stop(grace=0.5)
            if self.dynamic.account is not None:
                await self.accounts.delete(self.dynamic.account.name, self.dynamic.account.password)
        await self.accounts.close()
        await super().stop()
        await asyncio.to_thread(sweep_run_dirs, self.workdir, self._own_workdir)

    def _dynamic_prefix(self, rapp: str) -> str:
        return f"dyn-{self.robot_id}-{rapp}".replace("_", "-")

    def in_background(self, coro) -> asyncio.Task:
        """Run `coro` beside the Core's behaviours (cancelled at stop)."""
        task = asyncio.create_task(coro)
        self._background.add(task)
        task.add_done_callback(self._background.discard)
        return task

    async def _delete_account(self, session: DynamicSession) -> None:
        # after the reaping, which its destroy did not wait for: this record carries its exit code
        started = session.process is not None and session.process.pid is not None
        code = await session.process.wait() if started else None
        gone = await self.accounts.delete(session.account.name, session.account.password)
        self.record_structure("account-deleted" if gone else "account-kept", account=session.jid, exit_code=code)

    def _handoff(self) -> None:
        self.deactivate("user-listener")
        self.deactivate("microphone-listener")  # the RApp may use the microphone (word_spotting)
        self.deactivate("audio-listener")
        server = self.robot_commands.service()
        self.activate("command-server", server, server.make_template())
        self.activate("busy-chat", UserChat(self.owner, self._busy_chat))
        self.activate("heartbeats", HeartbeatMonitor(self._beat), heartbeat_template())
        self.hearing.start_task_listening()
        safety_distance = self.robot_commands.safety_distance
        if safety_distance:
            self.activate("safety", SafetyMonitor(self.robot_commands, period=self.safety_period))
            self.robot.protect(safety_distance)  # the same margin, checked by the robot at its own rate
        self.record_structure("handoff", to=self.dynamic.jid, rapp=self.dynamic.rapp, trigger=self.dynamic.trigger,
                              **({"schedule": self.dynamic.schedule_id} if self.dynamic.schedule_id else {}))
        self.dynamic.started = time.time()
        # the owner knows at once (chat only: the loudspeaker is the RApp's now)
        self.in_background(self.tell_user(f"Starting {self.dynamic.rapp}.", speak=False))

    def _beat(self, sender: str) -> None:
        d = self.dynamic
        if d is not None and sender == bare(d.jid):
            d.last_beat = time.monotonic()

    def _resume(self) -> None:
        self.deactivate("command-server")
        self.deactivate("busy-chat")
        self.deactivate("heartbeats")
        self.deactivate("safety")
        self.hearing.stop_task_listening()
        self.robot.protect(None)
        self.activate("user-listener", UserChat(self.owner, self._command_heard))
        self._listen_to_microphone()
        self.record_structure("resume", robot=self.robot_id)

    async def _watch_process(self, session: DynamicSession) -> None:
        code = await session.process.wait()
        if session.state in ("Finished", "Error"):
            self._end(session, session.detail)
            return
        words = await asyncio.to_thread(session.process.last_words, 4000)
        lines = [ln.strip() for ln in words.splitlines() if ln.strip()]
        why = crash_summary(words) or next((ln for ln in reversed(lines) if "Error" in ln or "rapp sandbox" in ln),
                                           lines[-1] if lines else "")
        self._end(session, f"process exited with code {code}" + (f": {why[:300]}" if why else ""))

    def _end(self, session: DynamicSession, reason: str) -> None:
        if not session.ended.is_set():
            session.end_reason = reason
            session.ended.set()
            session.ready.set()
            # forgiven_s: silence not counted (its own stalls, its link down): noticing a hang took that longer
            self.record_structure("ended", dynamic=session.jid, rapp=session.rapp, state=session.state,
                                  reason=reason, forgiven_s=round(session.forgiven_s, 2))

    # -- s8: serve until the Dynamic Agent ends --------------------------------------------
    async def serve_until_done(self) -> str:
        session = self.dynamic
        limit = session.manifest.time_limit_s
        start = prev = time.monotonic()
        paused = 0.0
        # silence before we watch is no evidence: the hand-over itself may have held our loop (a
        # fleet's Cores in one process entered s8 5 s after their hand-off, every beat unread)
        session.last_beat = max(session.last_beat, start)
        while not session.ended.is_set():
            now = time.monotonic()
            stall = now - prev - 0.1
            if self.robot_commands.estop_reason is not None:
                paused += now - prev  # a paused task's time limit does not run (up to an allowance)
            prev = now
            if stall > 0.2:  # our own loop was stalled (GIL, CPU): the Dynamic Agent is not to blame
                session.last_beat += stall
                session.forgiven_s += stall
            if getattr(self, "_reconnecting", False) or now - getattr(self, "_reconnected_at", 0) < 2.0:
                session.forgiven_s += max(0.0, now - session.last_beat)
                session.last_beat = now  # our own link was down: silence proves nothing
            silence = now - session.last_beat
            late = self._late_not_hung(session, now, silence)  # looks from the second missed beat on
            session.charged_s = charged_seconds(now - start, paused, self.strategies.pause_allowance_s)
            if silence > HEARTBEAT_TIMEOUT_S and session.state != "Finished" and not late:
                session.hung = True  # its loop does not run: it cannot log out, no grace
                self._end(session, f"no heartbeat for {silence:.1f}s (hung?)")
            elif session.charged_s > limit:
                waiting = self.strategies.waiting_for()
                self._end(session, f"time limit of {limit:g}s exceeded" + (f" while waiting for {waiting}"
                                                                          if waiting else ""))
            try:
                await asyncio.wait_for(session.ended.wait(), 0.1)
            except asyncio.TimeoutError:
                pass
        return session.end_reason

    def _late_not_hung(self, session: DynamicSession, now: float, silence: float) -> bool:
        """Whether a silence is the loaded machine's, not a hang (agents/liveness.py). Looks at the
        Dynamic Agent's process from the second missed beat on; False while the silence is shorter
        than the timeout."""
        pid = session.process.agent_pid if isinstance(session.process, AgentProcess) else None
        if pid is None or silence <= MARK_AFTER_S:
            session.silence = None  # a beat (or our own stall) ended the silence: the next starts afresh
            return False  # (a thread or in-process agent: nothing to look at)
        sample = sample_main_thread(pid)  # two small /proc reads: memory, not disk
        if session.silence is None:  # a new silence: its first look
            session.silence = SilenceWatch(now, sample)
        watch = session.silence
        watch.look(sample)
        if silence <= HEARTBEAT_TIMEOUT_S:
            return False
        why = watch.late_not_hung(sample, now) if silence <= GRACE_S else None
        if why and not watch.noted:
            watch.noted = True
            self.record_structure("heartbeat-late", dynamic=session.jid, rapp=session.rapp,
                                  silence=round(silence, 2), why=why)
        return why is not None

    # -- s10: destroy and resume ------------------------------------------------------------
    async def destroy_dynamic(self) -> None:
        session, self.dynamic = self.dynamic, None
        if session is None:
            self._resume_if_needed()
            return
        if "command-server" in self.active_behaviours():
            self.deactivate("command-server")  # no more robot commands from it, from now on
        self.events.end_subscriptions()
        await self.robot_commands.stop_robot()
        self.robot_commands.locks.free_all(session.jid)
        code = None
        if session.process is not None:
            if session.state in ("Finished", "Error"):  # it is logging out by itself: let it
                await session.process.logged_out(2.0)
            # resumed once it has logged out and been killed, not once the kernel has torn down its
            # process (exit code None meanwhile; a leftover run directory is swept at the next start)
            code = await session.process.end(grace=0.05 if session.hung else 1.0)
        outputs = session.workdir / "outputs"  # the RApp's files (Task.outputs), kept until the Core stops
        self.record_structure("destroy", dynamic=session.jid, rapp=session.rapp, state=session.state,
                              outputs=str(outputs) if outputs.is_dir() else None,
                              reason=session.end_reason, exit_code=code)
        self._resume_if_needed()  # supervising again at once; the rest is clean-up
        try:
            released = await self.request(self.platform, P.ReleaseCloudAgents(token=self.token, owner_jid=session.jid),
                                          timeout=5.0)
            for r in getattr(released, "refused", ()):
                _keep_refusal(session.refusals, {"by": r.by, "what": r.what, "why": r.why, "count": r.count})
        except RequestError as e:
            log.info("no cloud agent to stop for %s: %s", session.jid, e)
        shutil.rmtree(session.workdir / "package", ignore_errors=True)
        if session.account is not None:  # awaited at stop, not cancelled (else the next start sweeps it)
            deletion = asyncio.create_task(self._delete_account(session))
            self._deletions.add(deletion)
            deletion.add_done_callback(self._deletions.discard)
        refused = ""
        if session.refusals:  # told, not hidden: the owner learns what the RApp tried
            self.last_refusals = list(session.refusals)
            self.record_structure("refusals", dynamic=session.jid, rapp=session.rapp, refused=session.refusals)
            refused = " " + refusal_summary(session.refusals)
        else:
            self.last_refusals = []
        if session.state == "Finished":  # told once its Cloud Agents are gone too
            await self.tell_user(f"{session.rapp} finished.{refused}")
        elif session.started is None:  # never handed the robot (s6 failed)
            await self.tell_user(f"The application {session.rapp} did not start: {session.end_reason}{refused}")
        else:
            await self.tell_user(f"{session.rapp} ended with a problem: {session.end_reason or session.detail}{refused}")
        await self._tell_task_end(TaskRecord(
            robot_id=self.robot_id, command=session.command, rapp=session.rapp, version=session.version,
            stage=TaskStage.RUN if session.started is not None else TaskStage.START, state=session.state,
            ok=session.state == "Finished" and not session.refusals, reason=session.end_reason or session.detail,
            told=self.told[-1], reports=session.reports, refusals=[RefusalRecord(**r) for r in session.refusals],
            outputs=str(outputs) if outputs.is_dir() else None, started=session.started, ended=time.time(),
            trigger=session.trigger, schedule_id=session.schedule_id))

    def _resume_if_needed(self) -> None:
        if "user-listener" not in self.active_behaviours():
            self._resume()

    def note_refusal(self, sender: str, action: str, refusal) -> None:
        trace_refusal(self, sender, action, refusal)
        d = self.dynamic
        if d is not None and sender == bare(d.jid):
            _keep_refusal(d.refusals, {"by": self.address, "what": action, "why": refusal.reason[:200], "count": 1})

    def _sandbox_refused(self, session: DynamicSession, refusal: dict) -> None:
        self.record_structure("refused", by="sandbox", sender=session.jid, action=refusal["what"],
                              reason=refusal.get("why", ""), count=refusal["count"], rapp_account=True)
        _keep_refusal(session.refusals, {"by": "sandbox", "what": refusal["what"], "why": refusal.get("why", ""),
                                         "count": refusal["count"]})

    # -- services to the Dynamic Agent ------------------------------------------------------
    def _from_dynamic(self, ctx) -> DynamicSession:
        d = self.dynamic
        if d is None or ctx.sender != bare(d.jid):
            raise Refusal(f"{ctx.sender} is not the current Dynamic Agent", ErrorCode.NOT_SUPERVISOR)
        return d

    async def _on_status(self, req: C.TaskStatus, ctx) -> Done:
        d = self._from_dynamic(ctx)
        d.state, d.detail, d.last_beat = req.state.value, req.detail, time.monotonic()
        self.record_structure("status", dynamic=d.jid, state=d.state, detail=req.detail[:200])
        if req.state == C.TaskState.INIT:
            d.ready.set()
        elif req.state in (C.TaskState.FINISHED, C.TaskState.ERROR):
            self._end(d, req.detail or req.state.value)
        return Done()

    async def _on_report(self, req: C.Report, ctx) -> Done:
        d = self._from_dynamic(ctx)
        report = ReportRecord(text=req.text, data=req.data, stamp=time.time())
        d.reports.append(report)
        # a RApp that has just said the text itself marks it `said`: chat only, not a second time aloud.
        # In the chat its words are labelled as its own: the Core does not vouch for them
        await self.tell_user(req.text, speak=not req.data.get("said", False), label=d.rapp)
        await self.tell_watchers(TaskReported(robot_id=self.robot_id, rapp=d.rapp, report=report))
        return Done()

    # -- the owner's task records (ontology/results.py) --------------------------------------
    async def _on_subscribe_tasks(self, req: SubscribeTasks, ctx) -> Done:
        if ctx.sender != bare(self.owner):
            raise Refusal(f"{ctx.sender} is not the owner of {self.robot_id}", ErrorCode.PERMISSION)
        self.task_watchers.add(ctx.sender)
        return Done()

    async def tell_watchers(self, content: TaskReported | TaskEnded | ScheduleChanged) -> None:
        for jid in list(self.task_watchers):
            try:
                await self.notify(jid, content, ontology=content.ontology_name, action=content.action_name)
            except Exception as e:  # noqa: BLE001 - the owner's client gone: the task and the chat go on
                log.warning("%s to %s failed: %s", content.action_name, jid, e)

    async def _tell_task_end(self, record: TaskRecord) -> None:
        self._command_told = None  # this command's end is told
        await self.tell_watchers(TaskEnded(record=record.fitted()))

    async def _command_failed(self) -> None:
        """The command in hand ended before a task ran (s4-s6 failed, the owner was told why): its record."""
        if self._command_told is None:
            return
        command, told = self._command_told
        stage = (TaskStage.START if "package" in self.memory or "missed" in self.memory
                 else TaskStage.DOWNLOAD if "rapp" in self.memory else TaskStage.UNDERSTAND)
        said = self.told[told:]
        start = self._trigger
        await self._tell_task_end(TaskRecord(robot_id=self.robot_id, command=command, rapp=self.memory.get("rapp", ""),
                                             stage=stage, ok=False, reason=said[-1] if said else "not understood",
                                             told=said[-1] if said else "", ended=time.time(),
                                             trigger=TaskTrigger.SCHEDULED if start else TaskTrigger.COMMAND,
                                             schedule_id=start.schedule.id if start else None))

    async def _on_release_stop(self, req: C.ReleaseStop, ctx) -> Done:
        """The supervising RApp releases a stop its robot's safety latched (never the owner's)."""
        self._from_dynamic(ctx)
        latch = self.robot_commands
        if latch.estop_reason is None:
            return Done()
        if latch.estop_by == "owner":
            raise Refusal("the owner stopped the robot: only the owner can resume it", ErrorCode.PERMISSION)
        await latch.resume_motion(by=bare(ctx.sender))
        return Done()

    async def _on_get_state(self, req: C.GetState, ctx) -> C.CoreState:
        """Told to its supervisor (the running Dynamic Agent), its owner and the Platform only: the
        current RApp and Dynamic Agent are nobody else's business."""
        d = self.dynamic
        if ctx.sender not in {bare(self.owner), bare(self.platform)} and not (d is not None and ctx.sender == bare(d.jid)):
            raise Refusal(f"{ctx.sender} may not read {self.address}'s state", ErrorCode.FORBIDDEN)
        return C.CoreState(state=self.supervisor.behaviour.current or "" if self.supervisor else "",
                           active_behaviours=sorted(self.active_behaviours()),
                           dynamic_agent=d.jid if d else None, rapp=d.rapp if d else None)

    # -- talking to the user ----------------------------------------------------------------
    async def tell_user(self, text: str, speak: bool = True, label: str = "") -> None:
        """Chat at once; speak beside listening: the Core never waits for its own sentence
        (utterances queue behind one another, in order). `label`: whose words these are when they are
        not the Core's own (a RApp's report), put before them in the chat."""
        self.told.append(text)
        await self.send(Message(to=self.owner, body=f"[{label}] {text}" if label else text))
        if self.say_reports and speak:
            self.sentences_begun += 1  # without the loudspeaker's times the listener drops sound made meanwhile
            previous = self._speech
            self._speech = asyncio.create_task(self._say_after(previous, text))
            self._background.add(self._speech)
            self._speech.add_done_callback(self._background.discard)

    async def _say_after(self, previous: asyncio.Task | None, text: str) -> None:
        if previous is not None:
            await asyncio.gather(previous, return_exceptions=True)
        try:
            await self.robot.handle(ontology.robot.Say(text=text))
        except Exception:  # noqa: BLE001 - a robot without speech still gets the chat
            pass

    async def _busy_chat(self, text: str) -> None:
        self.record_structure("command", text=text[:200], busy=True)
        d = self.dynamic
        word = text.lower().strip(" .!")
        if word in CANCEL_WORDS:
            if d is not None:
                self._end(d, "cancelled by the user")  # the reason, before the task's own failure
            await self.robot_commands.stop_robot(everything=True)
            return
        if word in STOP_WORDS:  # the task pauses (its motions are held) until "resume" or "cancel"
            await self.robot_commands.emergency_stop("stopped by the user")
            return
        if word in RESUME_WORDS:
            await self.robot_commands.resume_motion()
            return
        if await self._schedule_while_busy(text):
            return
        waiting = self.strategies.waiting_for()
        await self.tell_user(f"I am busy with {d.rapp if d else 'a task'}" + (f", waiting for {waiting}" if waiting
                                                                               else "")
                             + "; say \"stop\" to pause it, \"cancel\" to end it.")

    async def _schedule_while_busy(self, text: str) -> bool:
        """A schedule asked for while a task runs (the chat's path: "check the hazards at 22:00"):
        kept or refused now (busy until the task may end). False: the words name no schedule."""
        if len(_words(text)) < 2 or not self.catalogue:
            return False
        try:
            found = await self.interpret(text)
        except RequestError:
            return False
        if found.schedule is None:
            return False
        await self.scheduler.handle(found.schedule, found.rapp, dict(found.parameters), text)
        return True


def _keep_refusal(kept: list[dict], refusal: dict, limit: int = 50) -> None:
    """One entry per (by, what, why), counted."""
    same = next((r for r in kept if (r["by"], r["what"], r["why"]) == (refusal["by"], refusal["what"], refusal["why"])),
                None)
    if same is not None:
        same["count"] = max(same["count"] + (refusal["by"] != "sandbox"), refusal["count"])
    elif len(kept) < limit:
        kept.append(dict(refusal))


def refusal_summary(refusals: list[dict], limit: int = 600) -> str:
    """What a run was refused, in one sentence for its owner."""
    n = sum(r["count"] for r in refusals)
    items = [f"{r['what']} ({r['by'].split('@')[0]}{': ' + r['why'] if r['why'] else ''})"
             + (f" x{r['count']}" if r["count"] > 1 else "") for r in refusals]
    text = f"It was refused {n} operation{'s' if n != 1 else ''}: " + "; ".join(items)
    return (text[:limit - 3] + "...") if len(text) > limit else text + "."
