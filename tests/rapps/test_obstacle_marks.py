"""The SDK's obstacle marks against the Platform's real obstacle layer and planner (issue 48.6, NAO,
generated house 52169): a passage door the map shows open stood at 59 deg, its leaf's tip in the way. A
disc round the echo closed the one doorway for good; a core at the echo with a body behind it closes it
too, but without the body (`relax`) the planner finds the gap the leaf left and keeps clear of the leaf."""
from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from agents.errors import RequestFailed
from agents.services import navigation, obstacles
from agents.services.context import ServiceContext, ServiceState
from agents.services.errors import ServiceError
from agents.services.maps import GridMap
from ontology.robot_types import ROBOT_TYPES
from ontology.services.common import Pose2D
from ontology.services.navigation import PLAN_FOUND, AddObstacle, ClearObstacles, ListObstacles, PlanPath2D
from rapps.sdk.monitor import ECHO_RADIUS_M, ObstacleMarks, behind

RES = 0.05
HINGE, WIDTH, OPEN_DEG = (3.0, 1.5), 1.0, 59.0  # the doorway: x = 3 m, y 1.5-2.5; the leaf swings west
TIP = (HINGE[0] - WIDTH * math.sin(math.radians(OPEN_DEG)), HINGE[1] + WIDTH * math.cos(math.radians(OPEN_DEG)))
SEEN_FROM = (TIP[0] - 0.55, TIP[1] + 0.17)  # where the robot stood after backing off (52169: 0.55 m west)
START, GOAL = (TIP[0] - 0.6, 2.2), (4.5, 2.0)


MAPPED_DEG = 85.0  # the leaf as the map has it


def one_doorway() -> GridMap:
    """6 m x 4 m, one wall at x = 3 m with a 1 m doorway (y 1.5-2.5), its leaf mapped at 85 deg."""
    b = np.zeros((80, 120), bool)
    b[0, :] = b[-1, :] = b[:, 0] = b[:, -1] = True
    b[:, 59:61] = True
    b[int(1.5 / RES):int(2.5 / RES), 59:61] = False
    a = math.radians(MAPPED_DEG)
    for s in np.linspace(0.0, WIDTH, 60):
        x, y = HINGE[0] - s * math.sin(a), HINGE[1] + s * math.cos(a)
        b[int(y / RES), int(x / RES)] = b[int(y / RES) + 1, int(x / RES)] = True
    return GridMap("home", b, RES, (0.0, 0.0, 0.0))


class Platform:
    """The Platform's obstacle and planning services as the task's proxy calls them (a refusal comes
    back as the proxy raises it)."""

    def __init__(self, ctx: ServiceContext):
        self.ctx = ctx

    async def path_planning_add_obstacle(self, **kw):
        try:
            return obstacles.add_obstacle(AddObstacle(**kw), self.ctx)
        except ServiceError as e:
            raise RequestFailed(e.reason, code=e.code) from None

    async def path_planning_clear_obstacles(self, **kw):
        return obstacles.clear_obstacles(ClearObstacles(**kw), self.ctx)


class Task:
    log = logging.getLogger("test")

    def __init__(self, ctx: ServiceContext):
        self.platform, self.traced = Platform(ctx), []

    async def subscribe(self, *topics, handler):
        pass

    def _trace(self, kind, **fields):
        self.traced.append(fields)


@pytest.fixture
def ctx(tmp_path):
    state = ServiceState(work_dir=tmp_path)
    state.maps.add_shared(one_doorway())
    return ServiceContext(state=state, user="alice")


def plan(ctx):
    req = PlanPath2D(map_id="home", robot_type="nao", start=Pose2D(x=START[0], y=START[1], theta=0.0),
                     goal=Pose2D(x=GOAL[0], y=GOAL[1], theta=0.0))
    return navigation.plan_path_2d(req, ctx)


def leaf_distance(p) -> float:
    ax, ay = HINGE
    dx, dy = TIP[0] - ax, TIP[1] - ay
    t = max(0.0, min(1.0, ((p[0] - ax) * dx + (p[1] - ay) * dy) / (dx * dx + dy * dy)))
    return math.hypot(p[0] - ax - t * dx, p[1] - ay - t * dy)


def test_the_gap_beside_the_leaf_is_wide_enough_and_the_old_disc_closes_it(ctx):
    assert plan(ctx).plan_found == PLAN_FOUND  # the map alone: straight through
    gap = WIDTH * math.sin(math.radians(OPEN_DEG))  # from the far jamb to the leaf
    assert gap > 2 * ROBOT_TYPES["nao"].clearance_radius_m + 0.1
    obstacles.add_obstacle(AddObstacle(map_id="home", x=TIP[0], y=TIP[1], radius_m=0.25), ctx)
    assert plan(ctx).plan_found != PLAN_FOUND


async def test_a_core_and_a_body_close_the_gap_the_core_alone_leaves_it_open(ctx):
    marks = ObstacleMarks(Task(ctx))
    mark = await marks.enter("home", *TIP, radius_m=0.25, seen_from=SEEN_FROM, skip_within_m=0.12)
    layer = obstacles.list_obstacles(ListObstacles(map_id="home"), ctx).obstacles
    body = behind(SEEN_FROM, TIP, 0.25)
    assert sorted((round(o.x, 3), round(o.y, 3), o.radius_m) for o in layer) == sorted(
        [(round(TIP[0], 3), round(TIP[1], 3), ECHO_RADIUS_M), (round(body[0], 3), round(body[1], 3), 0.25)])
    assert math.dist(body, SEEN_FROM) == pytest.approx(math.dist(TIP, SEEN_FROM) + 0.25)  # behind the echo
    assert plan(ctx).plan_found != PLAN_FOUND
    assert await marks.relax() == 1 and list(marks.marks) == [mark] and marks.bodies == {}
    reply = plan(ctx)
    assert reply.plan_found == PLAN_FOUND
    pts = [(p.x, p.y) for p in reply.path]
    assert any(abs(x - 3.0) < 0.2 for x, _ in pts)  # through the doorway
    # the leaf was never on the map: the route round the tip keeps the robot's clearance of it
    along = [(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])) for a, b in zip(pts, pts[1:]) for t in np.linspace(0, 1, 11)]
    assert min(leaf_distance(p) for p in along) >= ROBOT_TYPES["nao"].clearance_radius_m - 0.05
    await marks.clear(mark)
    assert obstacles.list_obstacles(ListObstacles(map_id="home"), ctx).obstacles == []


async def test_clearing_a_core_takes_its_body_with_it_and_a_wall_echo_enters_neither(ctx):
    marks = ObstacleMarks(Task(ctx))
    assert await marks.enter("home", 2.97, 1.0, radius_m=0.25, seen_from=(2.5, 1.0), skip_within_m=0.12) == ""
    assert obstacles.list_obstacles(ListObstacles(map_id="home"), ctx).obstacles == []
    mark = await marks.enter("home", *TIP, radius_m=0.25, seen_from=SEEN_FROM)
    assert len(obstacles.list_obstacles(ListObstacles(map_id="home"), ctx).obstacles) == 2
    await marks.clear(mark)
    assert obstacles.list_obstacles(ListObstacles(map_id="home"), ctx).obstacles == [] and marks.bodies == {}


async def test_an_event_clearing_a_mark_while_the_bodies_are_relaxed_or_a_refused_body_breaks_nothing(ctx):
    """The obstacle-clear event's handler runs as a task of its own: it may clear a mark while relax()
    waits on the Platform (a KeyError ended the hazard), or clear one the task clears too. A body the
    Platform refuses (its centre off the map) leaves the core marked and the task going."""
    task = Task(ctx)
    marks = ObstacleMarks(task)
    first = await marks.enter("home", *TIP, radius_m=0.25, seen_from=SEEN_FROM)
    second = await marks.enter("home", TIP[0], TIP[1] - 0.6, radius_m=0.25, seen_from=SEEN_FROM)
    clear_at = task.platform.path_planning_clear_obstacles

    async def clearing_meanwhile(**kw):  # the event clears the other mark while the first body is cleared
        if second in marks.marks:
            await marks.clear(second)
        return await clear_at(**kw)

    task.platform.path_planning_clear_obstacles = clearing_meanwhile
    assert await marks.relax() == 1 and marks.bodies == {} and list(marks.marks) == [first]
    task.platform.path_planning_clear_obstacles = clear_at
    await marks.clear(first)
    await marks.clear(first)  # twice: the event and the task
    assert obstacles.list_obstacles(ListObstacles(map_id="home"), ctx).obstacles == []
    edge = await marks.enter("home", 0.3, 2.0, radius_m=0.6, seen_from=(1.0, 2.0))  # the body's centre: x < 0
    assert edge and edge in marks.marks and marks.bodies == {}
    assert [(o.x, o.y, o.radius_m) for o in obstacles.list_obstacles(ListObstacles(map_id="home"), ctx).obstacles] == [
        (0.3, 2.0, ECHO_RADIUS_M)]
