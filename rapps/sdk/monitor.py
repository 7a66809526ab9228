"""Plan monitoring (paper 004): a plan carries expectations, a monitor checks them while the plan runs.

    monitor = PlanMonitor(task, ArriveBy(goal, within_s=60), PathFree(path), Localized(lambda: ekf.std_m, 0.15))
    try:
        await monitor.run(task.robot.move_along_path(poses=path, _timeout=900))
    except PlanFailed as e:        # e.expectation, e.reason, e.obstacle (x, y) or None
        if e.obstacle:
            await task.marks.enter(map_id, *e.obstacle, note="something in the way")   # the Platform's layer
        ...re-plan (plans avoid the marks)

When an expectation fails the monitor blocks execution (the robot's base is stopped, the motion's request
abandoned) and raises PlanFailed, traced as a structure record `plan-failed`. Expectations:

    ArriveBy(goal, within_s)   where the robot should be, by when: the motion ends within `within_s`
                               seconds of unpaused time and the robot's pose estimate is then within
                               `tolerance_m` of the goal
    PathFree(path)             the path stays free: fails when the Core's reactive strategies gave up
                               (the motion failed with code `blocked`), or (patience_s) when an obstacle
                               the range sensors see stands on the rest of the path that long; the
                               obstacle's place comes from the Core's obstacle events
    Localized(std_m, max_m)    the localization stays certain: `std_m()` stays within `max_m`

`ObstacleMarks` (task.marks) enters obstacles into the Platform's temporary obstacle layer and takes each
out again when the range sensors see its place free (the Core's obstacle-clear event), or it expires.
Entered with where the robot stood (`seen_from`), a mark is a small core at the echo and a body behind
it; `relax()` drops the bodies (the hazard task calls it when they close every route: a gap narrowed,
not closed).
Time spent paused (emergency stop) does not count against any deadline, up to the monitor's
`pause_allowance_s` (2 minutes): a motion held for ever still fails its deadline."""
from __future__ import annotations

import asyncio
import math
from typing import Any, Awaitable, Callable, Iterable, NoReturn

from agents.errors import RequestError, RequestFailed
from ontology.errors import ErrorCode
from ontology.notifications import EventTopic, Notification
from ontology.trace import RecordKind, StructureEvent

Point = tuple[float, float]


class PlanFailed(Exception):
    """An expectation of the running plan failed; the robot has been stopped. `backed_off`: the Core's
    reactive strategies already backed the robot away from the obstacle (agents/core_strategies.py)."""

    def __init__(self, expectation: str, reason: str, obstacle: Point | None = None, backed_off: bool = False):
        super().__init__(f"{expectation}: {reason}")
        self.expectation, self.reason, self.obstacle = expectation, reason, obstacle
        self.backed_off = backed_off


def echo_point(data: dict[str, Any]) -> Point | None:
    """Where an obstacle event's nearest reading is, in the map frame (from the pose the Core sent)."""
    try:
        x, y, theta = data["pose"]
        r, b = float(data["range_m"]), float(data["bearing_rad"])
    except (KeyError, TypeError, ValueError):
        return None
    return x + r * math.cos(theta + b), y + r * math.sin(theta + b)


def distance_to_path(p: Point, path: list[Point]) -> float:
    if len(path) == 1:
        return math.dist(p, path[0])
    best = math.inf
    for a, b in zip(path, path[1:]):
        dx, dy = b[0] - a[0], b[1] - a[1]
        seg2 = dx * dx + dy * dy
        t = 0.0 if seg2 == 0 else max(0.0, min(1.0, ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / seg2))
        best = min(best, math.dist(p, (a[0] + t * dx, a[1] + t * dy)))
    return best


def _xy(poses: Iterable[Any]) -> list[Point]:
    """(x, y) of poses given as Pose2D, {"x", "y"} dicts or (x, y, ...) sequences."""
    return [(p.x, p.y) if hasattr(p, "x") else (float(p["x"]), float(p["y"])) if isinstance(p, dict)
            else (float(p[0]), float(p[1])) for p in poses]


class Expectation:
    """One thing the plan expects; `check` answers the reason it failed, or None."""

    name = "expectation"

    def check(self, elapsed_s: float) -> str | None:
        return None

    def on_event(self, note: Notification, elapsed_s: float) -> None:
        pass

    def on_motion_error(self, e: RequestError) -> str | None:
        """The motion failed: the reason when this expectation explains it (None: not mine)."""
        return None

    async def on_done(self, task: Any) -> str | None:
        """The motion finished: the reason when the result breaks this expectation."""
        return None

    obstacle: Point | None = None


class ArriveBy(Expectation):
    name = "arrive-by"

    def __init__(self, goal: Any, within_s: float, tolerance_m: float = 0.5):
        self.goal = _xy([goal])[0]
        self.within_s, self.tolerance_m = within_s, tolerance_m

    def check(self, elapsed_s: float) -> str | None:
        if elapsed_s > self.within_s:
            return f"not at ({self.goal[0]:.2f}, {self.goal[1]:.2f}) after {self.within_s:.0f} s"
        return None

    async def on_done(self, task: Any) -> str | None:
        pose = await task.robot.get_global_pose()
        off = math.dist((pose.x, pose.y), self.goal)
        if off > self.tolerance_m:
            return f"the motion ended {off:.2f} m from ({self.goal[0]:.2f}, {self.goal[1]:.2f})"
        return None


class PathFree(Expectation):
    name = "path-free"

    def __init__(self, path: Iterable[Any], clearance_m: float = 0.35, patience_s: float | None = None):
        self.path = _xy(path)
        self.clearance_m, self.patience_s = clearance_m, patience_s
        self.since: float | None = None  # when an obstacle on the path was first seen

    def on_event(self, note: Notification, elapsed_s: float) -> None:
        if note.topic == EventTopic.OBSTACLE_CLEAR:
            self.since = None
            return
        p = echo_point(note.data)
        if p is not None and distance_to_path(p, self.path) <= self.clearance_m:
            self.obstacle = p
            self.since = elapsed_s if self.since is None else self.since

    def check(self, elapsed_s: float) -> str | None:
        if self.patience_s is not None and self.since is not None and elapsed_s - self.since > self.patience_s:
            return f"an obstacle stood on the path for {self.patience_s:.0f} s"
        return None

    def on_motion_error(self, e: RequestError) -> str | None:
        if isinstance(e, RequestFailed) and e.code == ErrorCode.BLOCKED:
            self.backed_off = "the Core backed off" in e.reason
            return f"the way was blocked ({e.reason})"
        return None

    backed_off = False


class Localized(Expectation):
    name = "localized"

    def __init__(self, std_m: Callable[[], float], max_std_m: float):
        self.std_m, self.max_std_m = std_m, max_std_m

    def check(self, elapsed_s: float) -> str | None:
        std = self.std_m()
        if std > self.max_std_m:
            return f"position uncertain (std {std:.2f} m > {self.max_std_m:.2f} m)"
        return None


class PlanMonitor:
    """Runs one motion of a plan while checking its expectations every `period_s`. Paused time (an
    emergency stop) does not count against the deadlines for up to `pause_allowance_s` in all; beyond
    it counts, so a motion held for ever still fails its deadline."""

    def __init__(self, task: Any, *expectations: Expectation, period_s: float = 0.25,
                 pause_allowance_s: float = 120.0):
        self.task, self.expectations, self.period_s = task, list(expectations), period_s
        self.pause_allowance_s = pause_allowance_s
        self.elapsed_s = 0.0  # time since run() started less the paused time allowed
        self.paused_s = 0.0

    async def run(self, motion: Awaitable[Any]) -> Any:
        job = asyncio.ensure_future(motion)
        hub = None
        try:
            try:
                hub = await events_hub(self.task)
                hub.monitors.add(self)
            except RequestError as e:  # no obstacle events (the path is then watched by its deadline only)
                self.task.log.warning("plan monitor: no obstacle events: %s", e)
            loop = asyncio.get_running_loop()
            while True:
                before = loop.time()
                done, _ = await asyncio.wait({job}, timeout=self.period_s)
                step = loop.time() - before
                if self.task.paused and self.paused_s + step <= self.pause_allowance_s:
                    self.paused_s += step
                else:
                    self.elapsed_s += step
                if done:
                    return await self._finished(job)
                for ex in self.expectations:
                    reason = ex.check(self.elapsed_s)
                    if reason:
                        await self._block(job)
                        self._fail(ex, reason)
        finally:
            if hub is not None:
                hub.monitors.discard(self)
            if not job.done():
                job.cancel()

    async def _finished(self, job: asyncio.Future[Any]) -> Any:
        await asyncio.sleep(0)  # an event sent just before the motion's answer reaches the expectations first
        try:
            result = job.result()
        except RequestError as e:
            for ex in self.expectations:
                reason = ex.on_motion_error(e)
                if reason:
                    self._fail(ex, reason)
            raise
        for ex in self.expectations:
            reason = await ex.on_done(self.task)
            if reason:
                self._fail(ex, reason)
        return result

    def on_event(self, note: Notification) -> None:
        for ex in self.expectations:
            ex.on_event(note, self.elapsed_s)

    async def _block(self, job: asyncio.Future[Any]) -> None:
        """Stop the robot where it is: cancelling the motion's request sends the Core a FIPA cancel,
        and the Core stops the motion (rapps/sdk/_call.py)."""
        job.cancel()
        await asyncio.gather(job, return_exceptions=True)

    def _fail(self, ex: Expectation, reason: str) -> NoReturn:
        obstacle = getattr(ex, "obstacle", None)
        self.task._trace(RecordKind.STRUCTURE, event=StructureEvent.PLAN_FAILED, expectation=ex.name,  # noqa: SLF001 - the SDK's own Task
                         reason=reason, obstacle=list(obstacle) if obstacle else None)
        raise PlanFailed(ex.name, reason, obstacle, backed_off=getattr(ex, "backed_off", False))


ECHO_RADIUS_M = 0.08  # a mark's core: the echo itself, within the range sensors' bearing and the pose's error


class ObstacleMarks:
    """The obstacles this task entered into the Platform's temporary layer (`task.marks`).

    A mark entered with `seen_from` (where the robot stood) is what the range sensors can say: a small
    core disc at the echo, and a body disc behind it, its near edge at the echo (never over the space in
    front, which the sensors saw free). `relax()` drops the bodies: a half-open door's leaf or a box
    beside a doorway leaves a gap that a disc of the obstacle's guessed size closes, the cores alone
    do not. `marks` holds the cores (id -> (map id, the echo)); `bodies` core id -> (map id, body id,
    its centre)."""

    def __init__(self, task: Any) -> None:
        self.task = task
        self.marks: dict[str, tuple[str, Point]] = {}  # mark id -> (map id, where)
        self.bodies: dict[str, tuple[str, str, Point]] = {}

    async def enter(self, map_id: str, x: float, y: float, radius_m: float = 0.25, ttl_s: float = 120.0,
                    note: str = "", skip_within_m: float = 0.0, seen_from: Point | None = None,
                    echo_radius_m: float = ECHO_RADIUS_M) -> str:
        """Enter an obstacle; its mark's id, or "" when the Platform did not add it (the map's own walls
        lie within `skip_within_m` of it: what the robot met is mapped already). Without `seen_from` a
        disc of `radius_m` centred at (x, y); with it, a core of `echo_radius_m` there and a body of
        `radius_m` beyond it, seen from `seen_from`."""
        await events_hub(self.task)  # so that a place seen free again clears its mark
        core = radius_m if seen_from is None else min(radius_m, echo_radius_m)
        layer = await self.task.platform.path_planning_add_obstacle(
            map_id=map_id, x=x, y=y, radius_m=core, ttl_s=ttl_s, note=note, skip_within_m=skip_within_m)
        added: str = layer.added
        if not added:
            return ""
        self.marks[added] = (map_id, (x, y))
        body = behind(seen_from, (x, y), radius_m) if seen_from is not None and radius_m > core else None
        body_id = ""
        if body is not None:
            try:  # the core is in: a body refused (its centre off the map, the layer full) leaves the core alone
                reply = await self.task.platform.path_planning_add_obstacle(
                    map_id=map_id, x=body[0], y=body[1], radius_m=radius_m, ttl_s=ttl_s, note=note)
                body_id = reply.added
            except RequestError as e:
                self.task.log.warning("the obstacle's body at (%.2f, %.2f) was not marked: %s", body[0], body[1], e)
            if body_id:
                self.bodies[added] = (map_id, body_id, body)
        self.task._trace(RecordKind.STRUCTURE, event=StructureEvent.OBSTACLE_MARKED, mark=added,  # noqa: SLF001 - the SDK's own Task
                         x=round(x, 3), y=round(y, 3), radius_m=core, note=note,
                         **({"body": [round(body[0], 3), round(body[1], 3), radius_m], "body_mark": body_id}
                            if body is not None and body_id else {}))
        return added

    def near(self, point: Point, within_m: float) -> list[str]:
        return [k for k, (_, p) in self.marks.items() if math.dist(p, point) <= within_m]

    async def seen_free(self, note: Notification) -> None:
        """An obstacle-clear event: nothing within range_m ahead (±30°): marks there are gone."""
        try:
            x, y, theta = note.data["pose"]
            free_m = float(note.data["range_m"])
        except (KeyError, TypeError, ValueError):
            return
        for mark_id, (map_id, (mx, my)) in list(self.marks.items()):
            d = math.hypot(mx - x, my - y)
            bearing = math.remainder(math.atan2(my - y, mx - x) - theta, math.tau)
            if d < free_m - 0.1 and abs(bearing) <= 0.52:
                await self.clear(mark_id)

    async def relax(self, keep: Callable[[Point], bool] | None = None) -> int:
        """Drop the bodies, keeping the cores (what the sensors saw), and the bodies of the marks whose
        echo `keep` says (a closed door's doorway: its body is the door); how many were dropped."""
        dropped = 0
        for mark_id in [k for k in self.bodies if keep is None or k not in self.marks or not keep(self.marks[k][1])]:
            entry = self.bodies.get(mark_id)  # an obstacle-clear event may have cleared it while this waited
            if entry is None:
                continue
            map_id, body_id, (x, y) = entry
            if await self._clear_at(map_id, x, y):  # a body the Platform did not clear is still there
                self.bodies.pop(mark_id, None)
                dropped += 1
                self.task._trace(RecordKind.STRUCTURE, event=StructureEvent.OBSTACLE_CLEARED, mark=body_id,  # noqa: SLF001 - the SDK's own Task
                                 x=round(x, 3), y=round(y, 3), relaxed=mark_id)
        return dropped

    async def clear(self, mark_id: str) -> None:
        """Take a mark (its core and body) out of the Platform's layer; nothing when it is gone already
        (an obstacle-clear event and the task's own clearing may meet)."""
        entry = self.marks.pop(mark_id, None)
        if entry is None:
            return
        map_id, (x, y) = entry
        body = self.bodies.pop(mark_id, None)
        if body is not None and await self._clear_at(body[0], *body[2]):
            self.task._trace(RecordKind.STRUCTURE, event=StructureEvent.OBSTACLE_CLEARED, mark=body[1],  # noqa: SLF001 - the SDK's own Task
                             x=round(body[2][0], 3), y=round(body[2][1], 3), body_of=mark_id)
        if await self._clear_at(map_id, x, y):
            self.task._trace(RecordKind.STRUCTURE, event=StructureEvent.OBSTACLE_CLEARED, mark=mark_id,  # noqa: SLF001 - the SDK's own Task
                             x=round(x, 3), y=round(y, 3))

    async def _clear_at(self, map_id: str, x: float, y: float) -> bool:
        try:
            await self.task.platform.path_planning_clear_obstacles(map_id=map_id, x=x, y=y, radius_m=0.01)
        except RequestError as e:
            self.task.log.warning("could not clear the obstacle mark at (%.2f, %.2f): %s", x, y, e)
            return False
        return True


def behind(seen_from: Point, echo: Point, radius_m: float) -> Point | None:
    """The centre of a disc of `radius_m` whose near edge is at `echo`, seen from `seen_from`; None when
    the two coincide (no direction)."""
    d = math.dist(seen_from, echo)
    if d < 1e-6:
        return None
    return (echo[0] + radius_m * (echo[0] - seen_from[0]) / d, echo[1] + radius_m * (echo[1] - seen_from[1]) / d)


class _EventsHub:
    """One subscription per task to the obstacle events, handed to the running monitors and marks."""

    def __init__(self, task: Any) -> None:
        self.task = task
        self.monitors: set[PlanMonitor] = set()

    async def on_event(self, note: Notification) -> None:
        for m in list(self.monitors):
            m.on_event(note)
        if note.topic == EventTopic.OBSTACLE_CLEAR:
            await self.task.marks.seen_free(note)


async def events_hub(task: Any) -> _EventsHub:
    """The task's one hub, kept in its instance dictionary (a Task knows nothing of monitors)."""
    hub: _EventsHub | None = task.__dict__.get("_events_hub")
    if hub is None:
        hub = task.__dict__["_events_hub"] = _EventsHub(task)
        try:
            await task.subscribe(EventTopic.OBSTACLE, EventTopic.OBSTACLE_CLEAR, handler=hub.on_event)
        except BaseException:
            del task.__dict__["_events_hub"]  # the next monitor tries again
            raise
    return hub

