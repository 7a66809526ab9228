"""The RApp SDK: what a RApp author subclasses.

    from rapps.sdk import FSM, Task, Step

    class HelloTask(Task):
        def build(self):
            fsm = FSM("hello", initial="greet")
            fsm.add_state("greet", Step(self.greet), final=True)
            return fsm

        async def greet(self, memory):
            await self.robot.say(text=self.params.get("greeting", "Hello"))
            await self.report("I said hello")

`self.robot.<action>(**fields)` is a robot-API request executed by the Core (ontology "robot"),
`self.platform.<service>(**fields)` a Platform service (the token is added for you),
`self.marks` the obstacles it entered into the Platform's map (plan monitoring: rapps/sdk/monitor.py),
`self.cloud` the RApp's own Cloud Agent (`await self.cloud.start()` then
`await self.cloud.call("action", **fields)`), `self.params` the parameters of the user's command,
`await self.localize()` where the robot is by the home's QR landmarks (rapps/sdk/localize.py; its
odometry, `self.robot.get_global_pose()`, drifts).
Errors arrive as RequestRefused / RequestFailed / NotUnderstood / RequestTimeout (all RequestError),
re-exported here with their codes (`e.code == ErrorCode.FORBIDDEN`): a RApp package imports only this
SDK and the ontology (see docs/architecture.md).
`rapps.sdk.paths` cuts a planned path into legs (path_length, point_at, cut_path, first_leg);
`rapps.sdk.vision` holds the image and QR-geometry helpers the Platform's own services use;
`check_door(self, door)` and `check_light(self, lamp)` (rapps/sdk/checks.py) the hazard checks in one call.

A Cloud Agent part subclasses CloudService and registers its actions with @action under
`ontology=<its ONTOLOGY>`; each handler is `async def <action>(self, request) -> reply`.
"""
from __future__ import annotations

import asyncio
import logging
from pathlib import Path
from typing import Any, Awaitable, Callable

from agents.errors import CloudAgentLost, NotUnderstood, RequestError, RequestFailed, RequestRefused, RequestTimeout
from behaviours import FSM, Behaviour, Inverter, OneShot, Parallel, Retry, Selector, Sequence, Timeout, active_path
from ontology import core as C
from ontology import platform as P
from ontology.acl import Performative
from ontology.notifications import EventTopic, Notification, NotificationKind, SubscribeEvents
from ontology.registry import Content, Progress, lookup
from ontology.errors import ErrorCode

from ontology.trace import RecordKind

from .blackboard import Blackboard, BlackboardError, Key
from ._call import _Calls
from .calls import PlatformCalls, RobotCalls
from .checks import check_door, check_light, door_geometry, intrinsics
from .localize import Localizer, LocalizeSettings, PoseEstimate
from .step import Step
from .monitor import ArriveBy, Expectation, Localized, ObstacleMarks, PathFree, PlanFailed, PlanMonitor

__all__ = ["Task", "Step", "CloudService", "FSM", "Behaviour", "OneShot", "Sequence", "Selector", "Parallel",
           "Timeout", "Retry", "Inverter", "Key", "Blackboard", "BlackboardError", "CloudAgentLost", "RequestError", "RequestFailed",
           "RequestRefused", "NotUnderstood", "RequestTimeout", "ErrorCode", "Notification", "NotificationKind",
           "EventTopic", "PlanMonitor", "PlanFailed", "Expectation", "ArriveBy", "PathFree", "Localized",
           "check_door", "check_light", "door_geometry", "intrinsics", "Localizer", "LocalizeSettings", "PoseEstimate"]


class _Dynamic(_Calls):
    """`await proxy.<action>(**fields)` for an action registered after calls.py was generated."""

    def __getattr__(self, action: str) -> Callable[..., Awaitable[Content]]:
        if action.startswith("_"):
            raise AttributeError(action)
        lookup(self._ontology, action)  # ContentError naming the known actions when unknown

        async def call(_timeout: float | None = None, _feedback: Callable[[Progress], Any] | None = None,
                       **fields: Any) -> Content:
            reply: Content = await self._call(action, fields, _timeout, _feedback)
            return reply

        call.__name__ = action
        return call


class RobotProxy(_Dynamic, RobotCalls):
    """`self.robot`: the robot API, served by the Core (typed methods: rapps/sdk/calls.py)."""

    def __init__(self, agent: Any, core: str, timeout: float = 120.0):
        super().__init__(agent, core, "robot", timeout)


class PlatformProxy(_Dynamic, PlatformCalls):
    """`self.platform`: the Platform's services (typed methods: rapps/sdk/calls.py); the token is added.

    Where several Platform agents serve the domain (agents/platform_directory.py), the stateless
    services go to the least loaded of two agents offering them (the primary's directory, read at
    the first such call and every few seconds); everything else goes to the primary."""

    def __init__(self, agent: Any, platform: str, token: str, timeout: float = 60.0):
        super().__init__(agent, platform, P.ONTOLOGY, timeout, extra={"token": token})
        # the Dynamic Agent's (agents/platform_directory.py); without one, everything goes to `platform`
        self.chooser = getattr(agent, "platform_chooser", None)

    async def _call(self, action: str, fields: dict[str, Any], timeout: float | None,
                    feedback: Callable[[Progress], Any] | None = None, to: str | None = None) -> Any:
        chooser = self.chooser
        if chooser is None:
            return await super()._call(action, fields, timeout, feedback)
        target = await chooser.target(action)
        try:
            with chooser.track(target):
                return await super()._call(action, fields, timeout, feedback, to=target)
        except RequestRefused as e:
            if target == self._address or e.code not in (ErrorCode.NOT_SERVING, ErrorCode.BUSY, ErrorCode.UNAVAILABLE):
                raise
            chooser.forget(target)  # a replica gone or full: the primary answers this one
            with chooser.track(self._address):
                return await super()._call(action, fields, timeout, feedback)


CLOUD_RESTART_WAIT_S = 120.0  # past the Platform's own wait for a restarted Cloud Agent (start timeout + 10 s)


class CloudProxy:
    """The RApp's own Cloud Agent, started on demand through the Platform."""

    def __init__(self, agent: Any, platform: str, token: str, rapp: str, version: str, ontology: str | None):
        self._agent, self._platform, self._token = agent, platform, token
        self._rapp, self._version, self._ontology = rapp, version, ontology
        self.address: str | None = None
        self.lost: str | None = None  # why the Cloud Agent is gone (the Platform told its Dynamic Agent)
        self._serving = asyncio.Event()  # cleared while the Platform restarts it: calls wait
        self._serving.set()

    def told(self, reason: str, restarting: bool = False, restarted: bool = False) -> None:
        """The Platform's notice that the Cloud Agent's process ended (its Dynamic Agent relays it)."""
        if restarting:
            self._serving.clear()
            return
        self.lost = None if restarted else reason
        self._serving.set()

    async def start(self, timeout: float = 60.0) -> str:
        if self.address is None:
            reply = await self._agent.request(
                self._platform, P.StartCloudAgent(token=self._token, rapp=self._rapp,
                                                  version=self._version, owner_jid=self._agent.address),
                timeout=timeout)
            self.address = reply.jid
        return self.address

    async def call(self, action: str, _timeout: float = 60.0, _ontology: str | None = None, **fields: Any) -> Content:
        """The Cloud Agent's answer; CloudAgentLost when its process died (or, code
        "cloud-restarted", when the Platform restarted it while this call was in flight).
        `_ontology`: an action of another ontology the Cloud part serves (the SDK's localization)."""
        if not self._serving.is_set():  # being restarted: the Platform tells when it serves or is lost
            try:
                await asyncio.wait_for(self._serving.wait(), CLOUD_RESTART_WAIT_S)
            except asyncio.TimeoutError:  # lost, for this call and every later one
                self.told(f"no word from the Platform {CLOUD_RESTART_WAIT_S:.0f} s after it began restarting "
                          "the Cloud Agent")
        if self.lost:
            raise CloudAgentLost(self.lost, code=ErrorCode.CLOUD_LOST, peer=self.address or "")
        ontology = _ontology or self._ontology
        if not ontology:
            raise RuntimeError(f"RApp {self._rapp} declares no cloud ontology")
        if self.address is None:
            await self.start()
        reply: Content = await self._agent.request(self.address, lookup(ontology, action)(**fields), timeout=_timeout)
        return reply

    async def stop(self) -> None:
        if self.address is not None and not self.lost:
            address, self.address = self.address, None
            await self._agent.request(self._platform, P.StopCloudAgent(token=self._token, jid=address),
                                      timeout=15.0)


class TaskLog:
    """`self.log.info("...")`: a line in the run's trace (kind "log", with the behaviour state it was
    written in) and in the Dynamic Agent's Python log (its stderr.log in the run directory)."""

    def __init__(self, task: "Task", trace: Callable[..., None]):
        self._task, self._trace = task, trace
        self._py = logging.getLogger(f"rapp.task.{task.manifest.name}")

    def _write(self, level: str, message: str, *args: Any) -> None:
        text = message % args if args else message
        state = "/".join(self._task.state_path())
        getattr(self._py, level)("[%s] %s", state or "-", text)
        self._trace(RecordKind.LOG, level=level, message=text[:2000], state=state)

    def debug(self, message: str, *args: Any) -> None:
        self._write("debug", message, *args)

    def info(self, message: str, *args: Any) -> None:
        self._write("info", message, *args)

    def warning(self, message: str, *args: Any) -> None:
        self._write("warning", message, *args)

    def error(self, message: str, *args: Any) -> None:
        self._write("error", message, *args)


class Task:
    """Base class of a RApp's task. Implement `build()`; it returns a Behaviour (an FSM, a tree).

    What a task has: `robot`, `platform`, `cloud` (calls), `params` (the manifest's defaults and the
    command's slot values), `robot_info` (its robot: type, id, capabilities), `log`, `progress()`,
    `outputs` (a directory for the run's files), `bb` (the typed blackboard of the keys declared
    in `keys`) and `memory` (the same values, untyped)."""

    cloud_ontology: str | None = None  # the ontology name of the RApp's Cloud Agent actions
    keys: dict[str, Key] = {}  # the typed blackboard's keys (rapps/sdk/blackboard.py)

    def __init__(self, runtime: Any) -> None:
        self.runtime = runtime
        self.agent = runtime  # the DynamicAgent (a SPADE agent)
        self.params: dict[str, Any] = dict(runtime.params)
        self.manifest = runtime.manifest
        self.robot_info = runtime.robot_info  # ontology.spawn.RobotInfo: robot_id, robot_type, capabilities
        self.robot = RobotProxy(runtime, runtime.core)
        self.platform = PlatformProxy(runtime, runtime.platform, runtime.token)
        self.cloud = CloudProxy(runtime, runtime.platform, runtime.token, runtime.manifest.name,
                                runtime.manifest.version, self.cloud_ontology)
        self.root: Behaviour | None = None  # what build() returned (set by the runtime)
        self._localizer: Localizer | None = None
        self.memory: dict[str, Any] = getattr(runtime, "memory", {})
        self.log = TaskLog(self, self._trace)
        self.marks = ObstacleMarks(self)  # obstacles entered into the Platform's map (rapps/sdk/monitor.py)
        self.bb = Blackboard(self.keys, self.memory, writer=lambda: (self.state_path() or [""])[-1],
                             trace=self._trace)

    @property
    def localizer(self) -> Localizer:
        """The task's localization (rapps/sdk/localize.py): its pose filter, settings (from the
        manifest's params), the home's landmarks and statistics; `localize()` runs it."""
        if self._localizer is None:
            self._localizer = Localizer(self)
        return self._localizer

    async def localize(self) -> PoseEstimate:
        """Where the robot is, by the home's QR landmarks: looks where codes should be in view, has the
        Cloud Agent find them and solve the pose, fuses that with the odometry in the pose filter, sets
        the result on the robot (get_global_pose gives it from now on) and returns it with its
        uncertainty (`std_m`, `std_rad`, `cov`; `fixed` False: no code seen, the odometry's prediction;
        `unsure` True: the codes disagreed and it could not tell which were right, nothing fused).
        Needs `home_get_info` in the manifest's services, `vision` and `navigation` in its robot_api, and
        a Cloud part that is a `LandmarkCloud` (docs/sdk.md, "Where the robot is")."""
        return await self.localizer.localize()

    def _trace(self, kind: RecordKind, **fields: Any) -> None:
        tracer = getattr(self.runtime, "tracer", None)
        if tracer is not None:
            tracer.record(kind, agent=getattr(self.runtime, "address", ""), **fields)

    @property
    def paused(self) -> str | None:
        """The emergency stop's reason while it is latched, else None. Meanwhile the task is paused: no
        behaviour starts its next step, no FSM enters its next state, behaviour timeouts stop counting,
        and robot motions wait for the resume (one the stop interrupted is issued again if its target is
        absolute, e.g. move_along_path; a relative move_to fails with code `estop`)."""
        return getattr(self.runtime, "paused", None)

    async def wait_resumed(self) -> None:
        """Return when the task is not paused (at once if it is not)."""
        gate = getattr(self.runtime, "pause", None)
        if gate is not None:
            await gate.wait()

    async def release_stop(self) -> None:
        """Release an emergency stop the robot's safety check latched (say, after backing away from
        the obstacle); an owner's stop is refused (RequestRefused, code `permission`)."""
        await self.runtime.request(self.runtime.core, C.ReleaseStop(), timeout=30.0)

    def state_path(self) -> list[str]:
        """The states/children of the task's behaviour running now, outermost first."""
        return active_path(self.root) if self.root is not None else []

    def progress(self, fraction: float | None, text: str = "") -> None:
        """How far the task is (0..1, or None when unknown): shown live by `rapp run`."""
        if fraction is not None and not 0.0 <= fraction <= 1.0:
            raise ValueError(f"progress fraction must be within 0..1, got {fraction}")
        self._trace(RecordKind.PROGRESS, fraction=fraction, text=text[:200])

    @property
    def outputs(self) -> Path:
        """This run's output directory (pictures, logs): kept by the Core after the run ends and
        copied by `rapp run` into its result folder."""
        out = Path(self.runtime.package_dir).parent / "outputs"
        out.mkdir(exist_ok=True)
        return out

    def build(self) -> Behaviour:
        raise NotImplementedError("a Task must build its behaviour (an FSM of behaviours)")

    async def subscribe(self, *topics: str, handler: Callable[[Notification], Awaitable[Any]] | None = None) -> None:
        """FIPA subscribe to the Core's sensor events (EventTopic: "obstacle", "obstacle-clear",
        "estop", "person"): each arrives as a Notification (kind, topic, stamp, expires, data) to `handler` (a
        coroutine function, run as a task of its own) and to `next_event()`. Expired ones are dropped
        (and traced) before they reach you. Subscriptions end with the task."""
        wanted = [EventTopic(t) for t in topics]
        if handler is not None:
            for t in wanted:
                self.runtime.event_handlers.setdefault(t.value, []).append(handler)
        await self.runtime.request(self.runtime.core, SubscribeEvents(topics=wanted), timeout=30.0,
                                   performative=Performative.SUBSCRIBE)

    async def next_event(self, timeout: float | None = None) -> Notification:
        """The next Core event not yet taken (TimeoutError after `timeout` s; the newest 100 are kept)."""
        return await asyncio.wait_for(self.runtime.events.get(), timeout)

    async def report(self, text: str, **data: Any) -> None:
        """Tell the user something, through the Core (spoken and sent as chat; `said=True`: the
        task has already said it itself, the Core only sends it by chat)."""
        await self.runtime.request(self.runtime.core, C.Report(text=text, data=data), timeout=30.0)

    async def say(self, *lines: str) -> bool:
        """Say each line on the robot; False, and nothing more said, when the robot has no speech
        synthesis (an Elektron): a report then carries the text. Any other failure is raised."""
        for line in lines:
            try:
                await self.robot.say(text=line)
            except RequestFailed as e:
                if e.code != ErrorCode.UNSUPPORTED:
                    raise
                return False
        return True


class CloudService:
    """Base class of a RApp's Cloud Agent part: handlers named after its actions."""

    ontology: str = ""

    def __init__(self, runtime: Any) -> None:
        self.runtime = runtime
        self.agent = runtime

    def handlers(self, ontology: str | None = None) -> dict[str, Callable[[Any, Any], Awaitable[Any]]]:
        """Responder handlers `(request, ctx)` around the author's `async def <action>(self, request)`
        (of its `ontology`, or of another one it serves)."""
        from ontology.registry import actions

        def wrap(method: Callable[[Any], Awaitable[Any]]) -> Callable[[Any, Any], Awaitable[Any]]:
            async def handler(req: Any, ctx: Any) -> Any:
                return await method(req)
            return handler

        return {name: wrap(getattr(self, name)) for name in actions(ontology or self.ontology) if hasattr(self, name)}

    def served(self) -> dict[str, dict[str, Callable[[Any, Any], Awaitable[Any]]]]:
        """Handlers by ontology: the part's own and those of the classes it extends (a part that is
        a LandmarkCloud also serves the SDK's localization), each served by a responder of its own."""
        out: dict[str, dict[str, Callable[[Any, Any], Awaitable[Any]]]] = {}
        for cls in type(self).__mro__:
            ontology = cls.__dict__.get("ontology")
            if ontology and ontology not in out:
                out[ontology] = self.handlers(ontology)
        return out
