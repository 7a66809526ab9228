"""The hazard task's leg decisions: how far to walk before the next fix, and when to turn first."""
import math

import pytest

from ontology.services.common import Pose2D
from rapps.hazard_detection.hazard_detection.task import (first_leg, leg_to_fix, next_leg_action, path_length,
                                                          tracking_tolerance)

LEG, TURN_FIRST = 1.1, 0.8


def straight(dx: float, dy: float, n: int = 30) -> list[Pose2D]:
    return [Pose2D(x=dx * i / n, y=dy * i / n, theta=0.0) for i in range(n + 1)]


def test_leg_ahead_is_walked_full_length():
    action, turn, leg = next_leg_action(straight(3, 0), 0.0, LEG, TURN_FIRST, localized=True, turned=False)
    assert (action, leg) == ("move", LEG)
    assert turn == pytest.approx(0.0)


def test_leg_behind_turns_first():
    action, turn, leg = next_leg_action(straight(-3, 0), 0.0, LEG, TURN_FIRST, localized=True, turned=False)
    assert action == "turn" and abs(turn) == pytest.approx(math.pi) and leg == LEG


def test_big_turn_without_a_fix_after_it_halves_the_leg():
    # turned already for this leg, but the re-localization looked behind: the turn comes again unfixed
    action, turn, leg = next_leg_action(straight(0, -3), math.pi / 2, LEG, TURN_FIRST, localized=True, turned=True)
    assert action == "move" and turn == pytest.approx(-math.pi) and leg == LEG / 2


def test_failed_localization_halves_the_leg():
    assert next_leg_action(straight(3, 0), 0.0, LEG, TURN_FIRST, localized=False, turned=False)[2] == LEG / 2
    assert next_leg_action(straight(-3, 0), 0.0, LEG, TURN_FIRST, localized=False, turned=True)[2] == LEG / 4


def test_first_leg_cuts_the_path_near_the_leg_length():
    poses, final = first_leg(straight(3, 0), LEG / 2)
    assert not final and LEG / 2 <= poses[-1].x < LEG / 2 + 0.11
    poses, final = first_leg(straight(0.65, 0), LEG / 2)  # a quarter more than a leg: one leg
    assert final and poses[-1].x == pytest.approx(0.65)
    poses, final = first_leg(straight(0.75, 0), LEG / 2)  # more: cut, the rest is the next leg
    assert not final and poses[-1].x < 0.75


async def test_it_relocalizes_when_the_pose_is_uncertain_not_after_every_short_leg():
    """Issue 42: the NAO re-localized every few decimetres in a stop-and-replan loop (4,211 steps):
    now only at a standing pose, after a late leg, or when the pose filter no longer allows a leg of
    relocalize_leg_m."""
    from rapps.sdk.ekf import PoseEKF

    from .test_hazard_reports import FakeRuntime
    from rapps.hazard_detection.hazard_detection.task import HazardTask

    task = HazardTask(FakeRuntime())
    task.build()
    loc = task.localizer
    loc.ekf, loc.odom_ref = PoseEKF((0.0, 0.0, 0.0), 0.004, 0.002), (0.0, 0.0, 0.0)  # just fixed
    memory = {"leg_final": False, "leg_outcome": "blocked"}
    loc.moved(0.3)  # a short leg cut by an obstacle and the back-off: the NAO may still walk 0.49 m
    assert await task.uncertain(memory) is False
    assert await task.uncertain({**memory, "leg_final": True}) is True  # the standing pose: the check's fix
    assert await task.uncertain({**memory, "leg_outcome": "late"}) is True  # late or lost: look
    loc.moved(2.5)  # metres walked since the fix: the filter no longer allows a useful leg
    assert await task.uncertain(memory) is True


def test_a_leg_ends_where_the_head_can_fix_the_pose():
    """Issue 42: short legs walked from a drifting estimate through a doorway where no code is in reach
    (the NAO's 22.7 cm). A leg whose end cannot fix the pose is cut back to the last point that can, or
    runs on through the stretch to the next one, in one leg, while the filter allows it."""
    path = straight(4, 0, n=40)

    def codes_at(*spans):
        return lambda p: any(a <= p.x <= b for a, b in spans)

    assert leg_to_fix(path, 1.0, codes_at((0.0, 4.0)), blind_m=2.0) is None  # its end can fix: as it was
    poses, final = leg_to_fix(path, 1.0, codes_at((0.0, 0.75)), blind_m=2.0)  # a doorway from 0.8 m on
    assert not final and poses[-1].x == pytest.approx(0.7) and path_length(poses) == pytest.approx(0.7)
    poses, final = leg_to_fix(path, 1.0, codes_at((0.0, 0.3), (1.75, 4.0)), blind_m=2.0)  # through it in one leg
    assert not final and poses[-1].x == pytest.approx(1.8) and poses[0] == path[0]
    assert leg_to_fix(path, 1.0, codes_at((0.0, 0.3), (2.5, 4.0)), blind_m=2.0) is None  # too far blind
    poses, final = leg_to_fix(path, 1.0, codes_at((0.0, 0.3)), blind_m=5.0)  # the standing pose: the rest
    assert final and poses == path
    # beyond the stretch a weaker fix (far codes) is enough to end it; before it, only a certain one
    poses, _ = leg_to_fix(path, 1.0, codes_at((0.0, 0.3), (3.0, 4.0)), blind_m=2.0, weak=codes_at((0.0, 0.85), (1.5, 4.0)))
    assert poses[-1].x == pytest.approx(1.5)


async def test_it_relocalizes_where_the_leg_was_ended_for_a_fix():
    from .test_hazard_reports import FakeRuntime
    from rapps.hazard_detection.hazard_detection.task import HazardTask
    from rapps.sdk.ekf import PoseEKF

    task = HazardTask(FakeRuntime())
    task.build()
    task.localizer.ekf, task.localizer.odom_ref = PoseEKF((0.0, 0.0, 0.0), 0.004, 0.002), (0.0, 0.0, 0.0)
    memory = {"leg_final": False, "leg_outcome": "moved", "fix_at_end": True}
    assert await task.uncertain(memory) is True and "fix_at_end" not in memory
    assert await task.uncertain({"leg_final": False, "leg_outcome": "moved"}) is False  # fresh fix, short leg


def test_the_tracking_tolerance_is_the_papers_for_each_robot():
    from ontology.robot_types import robot_type

    from .test_hazard_reports import FakeRuntime

    param = FakeRuntime().params["tracking_tolerance_m"]  # the manifest's: none, so the robot type's
    for kind in ("nao", "elektron"):
        assert tracking_tolerance(param, kind) == robot_type(kind).paper_tracking_m
    assert robot_type("nao").paper_tracking_m == 0.20 and robot_type("elektron").paper_tracking_m == 0.15  # sec. 4
    assert tracking_tolerance(param, "rover") == 0.15 and tracking_tolerance(0.1, "nao") == 0.1
