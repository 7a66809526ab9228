"""The hazard task's leg decisions: how far to walk before the next fix, and when to turn first."""
import math

import pytest

from ontology.services.common import Pose2D
from rapps.hazard_detection.hazard_detection.task import first_leg, next_leg_action

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
