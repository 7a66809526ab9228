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
`self.cloud` the RApp's own Cloud Agent (`await self.cloud.start()` then
`await self.cloud.call("action", **fields)`), `self.params` the parameters of the user's command.
Errors arrive as RequestRefused / RequestFailed / NotUnderstood / RequestTimeout (all RequestError),
re-exported here with their codes (`e.code == ErrorCode.FORBIDDEN`): a RApp package imports only this
SDK and the ontology (see docs/architecture.md).
`rapps.sdk.vision` holds the image and QR-geometry helpers the Platform's own services use.

A Cloud Agent part subclasses CloudService and registers its actions with @action under
`ontology=<its ONTOLOGY>`; each handler is `async def <action>(self, request) -> reply`.
"""
from __future__ import annotations

from typing import Any, Awaitable, Callable

from agents.errors import CloudAgentLost, NotUnderstood, RequestError, RequestFailed, RequestRefused, RequestTimeout
from behaviours import FSM, Behaviour, OneShot
from ontology import core as C
from ontology import platform as P
from ontology.registry import Content, lookup
from ontology.errors import ErrorCode

__all__ = ["Task", "Step", "CloudService", "FSM", "Behaviour", "OneShot", "CloudAgentLost", "RequestError", "RequestFailed",
           "RequestRefused", "NotUnderstood", "RequestTimeout", "ErrorCode"]


class _Proxy:
    """`await proxy.<action>(**fields)` -> request to `address` in `ontology`; reply model back."""

    def __init__(self, agent, address: str, ontology: str, timeout: float = 30.0,
                 extra: dict | None = None):
        self._agent, self._address, self._ontology = agent, address, ontology
        self._timeout, self._extra = timeout, extra or {}

    def __getattr__(self, action: str) -> Callable[..., Awaitable[Content]]:
        if action.startswith("_"):
            raise AttributeError(action)
        model = lookup(self._ontology, action)

        async def call(_timeout: float | None = None, **fields) -> Content:
            for k, v in self._extra.items():
                if k in model.model_fields:
                    fields.setdefault(k, v)
            req = model(**fields)
            return await self._agent.request(self._address, req, timeout=_timeout or self._timeout)

        call.__name__ = action
        return call


class RobotProxy(_Proxy):
    def __init__(self, agent, core: str, timeout: float = 120.0):
        import ontology.robot  # noqa: F401 - registers the robot-API models
        super().__init__(agent, core, "robot", timeout)


class PlatformProxy(_Proxy):
    def __init__(self, agent, platform: str, token: str, timeout: float = 60.0):
        import ontology.services  # noqa: F401 - registers the service models
        super().__init__(agent, platform, P.ONTOLOGY, timeout, extra={"token": token})


class CloudProxy:
    """The RApp's own Cloud Agent, started on demand through the Platform."""

    def __init__(self, agent, platform: str, token: str, rapp: str, version: str, ontology: str | None):
        self._agent, self._platform, self._token = agent, platform, token
        self._rapp, self._version, self._ontology = rapp, version, ontology
        self.address: str | None = None
        self.lost: str | None = None  # why the Cloud Agent is gone (the Platform told its Dynamic Agent)

    async def start(self, timeout: float = 60.0) -> str:
        if self.address is None:
            reply = await self._agent.request(
                self._platform, P.StartCloudAgent(token=self._token, rapp=self._rapp,
                                                  version=self._version, owner_jid=self._agent.address),
                timeout=timeout)
            self.address = reply.jid
        return self.address

    async def call(self, action: str, _timeout: float = 60.0, **fields) -> Content:
        """The Cloud Agent's answer; CloudAgentLost when its process died (or, code
        "cloud-restarted", when the Platform restarted it while this call was in flight)."""
        if self.lost:
            raise CloudAgentLost(self.lost, code=ErrorCode.CLOUD_LOST, peer=self.address or "")
        if self.address is None:
            await self.start()
        if not self._ontology:
            raise RuntimeError(f"RApp {self._rapp} declares no cloud ontology")
        return await self._agent.request(self.address, lookup(self._ontology, action)(**fields),
                                         timeout=_timeout)

    async def stop(self) -> None:
        if self.address is not None and not self.lost:
            address, self.address = self.address, None
            await self._agent.request(self._platform, P.StopCloudAgent(token=self._token, jid=address),
                                      timeout=15.0)


class Task:
    """Base class of a RApp's task. Implement `build()`; it returns a Behaviour (usually an FSM)."""

    cloud_ontology: str | None = None  # the ontology name of the RApp's Cloud Agent actions

    def __init__(self, runtime):
        self.runtime = runtime
        self.agent = runtime  # the DynamicAgent (a SPADE agent)
        self.params: dict[str, Any] = dict(runtime.params)
        self.manifest = runtime.manifest
        self.robot_info = runtime.robot_info  # ontology.spawn.RobotInfo: robot_id, robot_type, capabilities
        self.robot = RobotProxy(runtime, runtime.core)
        self.platform = PlatformProxy(runtime, runtime.platform, runtime.token)
        self.cloud = CloudProxy(runtime, runtime.platform, runtime.token, runtime.manifest.name,
                                runtime.manifest.version, self.cloud_ontology)

    def build(self) -> Behaviour:
        raise NotImplementedError("a Task must build its behaviour (an FSM of behaviours)")

    async def report(self, text: str, **data: Any) -> None:
        """Tell the user something, through the Core (spoken and sent as chat)."""
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


class Step(OneShot):
    """A one-shot behaviour running `async fn(memory)`; its return value is the outcome value."""

    def __init__(self, fn: Callable[[dict], Awaitable[Any]], name: str | None = None, **kw):
        super().__init__(name or getattr(fn, "__name__", "step"), **kw)
        self.fn = fn

    async def action(self) -> Any:
        return await self.fn(self.memory)


class CloudService:
    """Base class of a RApp's Cloud Agent part: handlers named after its actions."""

    ontology: str = ""

    def __init__(self, runtime):
        self.runtime = runtime
        self.agent = runtime

    def handlers(self) -> dict:
        """Responder handlers `(request, ctx)` around the author's `async def <action>(self, request)`."""
        from ontology.registry import actions

        def wrap(method):
            async def handler(req, ctx):
                return await method(req)
            return handler

        return {name: wrap(getattr(self, name)) for name in actions(self.ontology) if hasattr(self, name)}
