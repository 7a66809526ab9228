"""The temporary obstacle layer of the Platform's cost maps: a RApp marks what blocked its plan, the
next plan goes round it (through the other doorway), marks go when cleared at the place or expired,
and one user's marks never change another user's plans."""
import math

import numpy as np
import pytest
from pydantic import ValidationError

from agents.services import navigation, obstacles
from agents.services.context import ServiceContext, ServiceState
from agents.services.errors import ServiceError
from agents.services.maps import GridMap
from agents.services.obstacles import MAX_MARKS, ObstacleLayers
from ontology.errors import ErrorCode
from ontology.robot_types import ROBOT_TYPES
from ontology.services.common import Pose2D
from ontology.services.navigation import (
    PLAN_FOUND, PLAN_NOT_FOUND, AddObstacle, ClearObstacles, ListObstacles, PlanPath2D,
)

RES = 0.05
WALL_X = 3.0
LOWER = (1.0, 1.9)  # y range of the doorway on the straight route
UPPER = (3.1, 4.0)
START, GOAL = (1.0, 1.45), (5.0, 1.45)
LOWER_DOOR = (WALL_X, sum(LOWER) / 2)
UPPER_DOOR = (WALL_X, sum(UPPER) / 2)


def two_doors() -> GridMap:
    """6 m x 5 m, a wall at x = 3 m with two 0.9 m doorways (y 1.0-1.9 and 3.1-4.0)."""
    b = np.zeros((100, 120), bool)
    b[0, :] = b[-1, :] = b[:, 0] = b[:, -1] = True
    b[:, 59:61] = True
    for y0, y1 in (LOWER, UPPER):
        b[int(round(y0 / RES)):int(round(y1 / RES)), 59:61] = False
    return GridMap("rooms", b, RES, (0.0, 0.0, 0.0))


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock():
    return Clock()


@pytest.fixture
def state(tmp_path, clock):
    s = ServiceState(work_dir=tmp_path, obstacles=ObstacleLayers(clock=clock))
    s.maps.add_shared(two_doors())
    return s


def as_user(state, user="alice"):
    return ServiceContext(user=user, state=state)


def plan(ctx, start=START, goal=GOAL, robot="elektron", **kw):
    return navigation.plan_path_2d(PlanPath2D(robot_type=robot, map_id="rooms", start=Pose2D(x=start[0], y=start[1]),
                                              goal=Pose2D(x=goal[0], y=goal[1]), **kw), ctx)


def mark(ctx, at, radius=0.3, **kw):
    return obstacles.add_obstacle(AddObstacle(map_id="rooms", x=at[0], y=at[1], radius_m=radius, **kw), ctx)


def door_crossed(reply) -> float:
    """y where the path crosses the wall line."""
    assert reply.plan_found == PLAN_FOUND, reply.reason
    pts = [(p.x, p.y) for p in reply.path]
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        if (x0 - WALL_X) * (x1 - WALL_X) <= 0 and x0 != x1:
            return y0 + (WALL_X - x0) / (x1 - x0) * (y1 - y0)
    raise AssertionError("the path does not cross the wall")


def through(reply, door) -> bool:
    return door[0] + 0.3 <= door_crossed(reply) <= door[1] - 0.3  # elektron's footprint inside the doorway


def test_a_mark_in_one_doorway_sends_the_plan_through_the_other(state):
    alice = as_user(state)
    direct = plan(alice)
    assert through(direct, LOWER) and direct.obstacles_used == 0
    layer = mark(alice, LOWER_DOOR, note="box")
    assert layer.added == "obs-1"
    assert [(o.id, o.x, o.y, o.radius_m, o.note) for o in layer.obstacles] == [("obs-1", *LOWER_DOOR, 0.3, "box")]
    assert layer.obstacles[0].expires_in_s == pytest.approx(120.0)
    detour = plan(alice)
    assert through(detour, UPPER), door_crossed(detour)
    assert detour.obstacles_used == 1 and detour.length_m > direct.length_m + 1.5
    centre = np.array(LOWER_DOOR)
    assert min(math.dist((p.x, p.y), centre) for p in detour.path) > 0.3 + navigation.robot_radius("elektron")
    assert obstacles.list_obstacles(ListObstacles(map_id="rooms"), alice) == layer.model_copy(update={"added": ""})


def test_an_obstacle_at_the_maps_own_wall_is_not_added_when_asked(state):
    """What the robot met within skip_within_m of a mapped wall is that wall (its pose was off)."""
    alice = as_user(state)
    near_wall = (WALL_X - 0.15, 2.5)  # the wall's face is 0.1 m away (cells 2.95-3.05 m)
    skipped = mark(alice, near_wall, skip_within_m=0.12)
    assert skipped.added == "" and skipped.obstacles == []
    assert mark(alice, near_wall, skip_within_m=0.05).added == "obs-1"
    assert mark(alice, LOWER_DOOR, skip_within_m=0.3).added == "obs-2"  # the doorway's jambs are 0.45 m off


def test_marks_in_both_doorways_leave_no_plan_and_say_why(state):
    alice = as_user(state)
    mark(alice, LOWER_DOOR)
    mark(alice, UPPER_DOOR, note="door d2 closed")
    reply = plan(alice)
    assert reply.plan_found == PLAN_NOT_FOUND and reply.obstacles_used == 2
    assert "temporary obstacle mark(s) on this map block every route" in reply.reason
    assert plan(alice, use_obstacles=False).plan_found == PLAN_FOUND


def test_clearing_the_place_seen_free_restores_the_short_route(state):
    alice = as_user(state)
    mark(alice, LOWER_DOOR)
    mark(alice, (1.5, 4.5), radius=0.2)
    nearby = obstacles.clear_obstacles(ClearObstacles(map_id="rooms", x=3.2, y=1.5, radius_m=0.1), alice)
    assert len(nearby.obstacles) == 2  # the mark's centre is 0.2 m away: not within 0.1 m
    layer = obstacles.clear_obstacles(ClearObstacles(map_id="rooms", x=3.2, y=1.5, radius_m=0.5), alice)
    assert [o.id for o in layer.obstacles] == ["obs-2"]
    reply = plan(alice)
    assert through(reply, LOWER) and reply.obstacles_used == 1
    assert obstacles.clear_obstacles(ClearObstacles(map_id="rooms", all=True), alice).obstacles == []
    assert plan(alice).obstacles_used == 0


def test_an_expired_mark_no_longer_counts(state, clock):
    alice = as_user(state)
    mark(alice, LOWER_DOOR, ttl_s=10.0)
    clock.now += 9.9
    assert through(plan(alice), UPPER)
    (left,) = obstacles.list_obstacles(ListObstacles(map_id="rooms"), alice).obstacles
    assert left.expires_in_s == pytest.approx(0.1)
    clock.now += 0.2
    reply = plan(alice)
    assert through(reply, LOWER) and reply.obstacles_used == 0
    assert obstacles.list_obstacles(ListObstacles(map_id="rooms"), alice).obstacles == []


def test_use_obstacles_false_ignores_the_marks(state):
    alice = as_user(state)
    mark(alice, LOWER_DOOR)
    reply = plan(alice, use_obstacles=False)
    assert through(reply, LOWER) and reply.obstacles_used == 0


def test_one_users_marks_leave_other_users_and_the_map_alone(state):
    alice, bob = as_user(state), as_user(state, "bob")
    base = state.maps.get("bob", "rooms")
    before = base.blocked.copy()
    mark(alice, LOWER_DOOR)
    assert through(plan(alice), UPPER)
    reply = plan(bob)
    assert through(reply, LOWER) and reply.obstacles_used == 0
    assert obstacles.list_obstacles(ListObstacles(map_id="rooms"), bob).obstacles == []
    assert np.array_equal(base.blocked, before)
    assert obstacles.clear_obstacles(ClearObstacles(map_id="rooms", all=True), bob).obstacles == []
    assert len(obstacles.list_obstacles(ListObstacles(map_id="rooms"), alice).obstacles) == 1


def test_overlays_are_reused_while_the_layer_is_unchanged(state):
    layers, base = state.obstacles, state.maps.get("alice", "rooms")
    assert layers.overlay("alice", base) is base
    layers.add("alice", base, *LOWER_DOOR, 0.3, 60.0)
    first = layers.overlay("alice", base)
    assert first is not base and first.base is base and layers.overlay("alice", base) is first
    assert first.blocked[int(1.45 / RES), int(WALL_X / RES)] and not base.blocked[int(1.45 / RES), int(WALL_X / RES)]
    layers.add("alice", base, 1.5, 4.5, 0.2, 60.0)
    second = layers.overlay("alice", base)
    assert second is not first
    layers.clear("alice", "rooms", 1.5, 4.5, 0.05)
    assert layers.overlay("alice", base) is first  # the same marks again: the same cost maps and graphs


def test_an_overlays_cost_map_and_components_match_the_full_computation(state):
    """The overlay inflates only around its marks and finds components without a graph: both must
    agree with inflating the whole map and with the graph's components."""
    from agents.services import planning

    layers, base = state.obstacles, state.maps.get("alice", "rooms")
    layers.add("alice", base, *LOWER_DOOR, 0.3, 60.0)
    layers.add("alice", base, *UPPER_DOOR, 0.3, 60.0)  # the rooms apart
    layers.add("alice", base, 5.9, 4.9, 0.4, 60.0)  # over the map's corner
    over = layers.overlay("alice", base)
    seen = set()
    for robot in ROBOT_TYPES:
        for margin in (0.0, 0.1):
            radius = (navigation.robot_radius(robot) + margin) / RES
            free = navigation.free_cells(over, robot, margin)
            assert np.array_equal(free, ~planning.inflate(over.blocked, radius))
            graph = planning.GridGraph(free)
            cells = [tuple(int(v) for v in c) for c in np.argwhere(free)[::97, ::-1]]
            for a, b in zip(cells, cells[1:] + cells[:1]):
                same = graph.component[graph.node(*a)] == graph.component[graph.node(*b)]
                assert navigation.connected(over, robot, margin, a, b) == same
                seen.add(bool(same))
    assert seen == {True, False}


@pytest.mark.parametrize("fields, problem", [
    ({"radius_m": 0.0}, "greater than 0.02"),
    ({"radius_m": 2.0}, "less than or equal to 1.5"),
    ({"x": float("nan")}, "finite number"),
    ({"y": float("inf")}, "finite number"),
    ({"ttl_s": 0.0}, "greater than 0"),
    ({"note": "x" * 201}, "at most 200"),
])
def test_bad_marks_are_refused_by_the_request_model(fields, problem):
    with pytest.raises(ValidationError, match=problem):
        AddObstacle(**{"map_id": "rooms", "x": 1.0, "y": 1.0, "radius_m": 0.3, **fields})


def test_bad_requests_get_clear_errors(state):
    alice = as_user(state)
    with pytest.raises(ValidationError, match=r"\(x, y\) or all=True"):
        ClearObstacles(map_id="rooms", x=1.0)
    for request, call in ((AddObstacle(map_id="nowhere", x=1.0, y=1.0, radius_m=0.3), obstacles.add_obstacle),
                          (ClearObstacles(map_id="nowhere", all=True), obstacles.clear_obstacles),
                          (ListObstacles(map_id="nowhere"), obstacles.list_obstacles)):
        with pytest.raises(ServiceError, match="unknown map 'nowhere'") as e:
            call(request, alice)
        assert e.value.code == ErrorCode.NOT_FOUND
    with pytest.raises(ServiceError, match="outside map") as e:
        mark(alice, (7.0, 1.0))
    assert e.value.code == ErrorCode.OUT_OF_RANGE
    for i in range(MAX_MARKS):
        mark(alice, (0.5 + 0.05 * (i % 100), 0.5), radius=0.05)
    with pytest.raises(ServiceError, match=f"already holds {MAX_MARKS}") as e:
        mark(alice, (1.0, 1.0))
    assert e.value.code == ErrorCode.TOO_LARGE
    assert len(mark(as_user(state, "bob"), (1.0, 1.0)).obstacles) == 1  # the limit is per user


def test_a_start_inside_a_marks_disc_backs_out_and_plans(state):
    """The robot stopped 0.6 m before the lower doorway and marked what it saw there with a disc that
    covers its own position: the plan steps away from the mark, then takes the upper doorway."""
    alice = as_user(state)
    start, centre, radius = (2.4, 1.45), np.array((3.0, 1.45)), 0.7
    mark(alice, centre, radius=radius)
    reply = plan(alice, start=start)
    assert through(reply, UPPER) and reply.obstacles_used == 1
    dist = [math.dist((p.x, p.y), centre) for p in reply.path]
    assert dist[0] < radius
    reach = radius + navigation.robot_radius("elektron")
    out = next(i for i, d in enumerate(dist) if d >= reach - 2 * RES)
    assert all(a <= b + 1e-6 for a, b in zip(dist[:out], dist[1:out + 1]))  # backs straight away
    assert min(dist[out:]) >= reach - 2 * RES


def test_a_goal_inside_a_mark_is_refused_with_the_reason(state):
    alice = as_user(state)
    mark(alice, (5.0, 1.45), radius=0.5)
    reply = plan(alice)
    assert reply.plan_found == PLAN_NOT_FOUND and "goal pose is in a temporary obstacle mark" in reply.reason
