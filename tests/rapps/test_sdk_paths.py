"""rapps/sdk/paths.py: a planned path cut into legs (the hazard RApp, lamp patrol and door audit)."""
from __future__ import annotations

import math

import pytest

from ontology.services.common import Pose2D
from rapps.sdk.paths import cut_path, first_leg, path_length, point_at

L = [Pose2D(x=0.0, y=0.0, theta=0.0), Pose2D(x=1.0, y=0.0, theta=0.0), Pose2D(x=1.0, y=2.0, theta=0.0)]


def test_length_and_points_along():
    assert path_length(L) == pytest.approx(3.0)
    p = point_at(L, 2.0)
    assert (p.x, p.y, p.theta) == pytest.approx((1.0, 1.0, math.pi / 2))
    assert point_at(L, 9.0) == L[-1]


def test_cut_ends_exactly_there_and_keeps_a_shorter_path_whole():
    leg = cut_path(L, 1.5)
    assert path_length(leg) == pytest.approx(1.5) and (leg[-1].x, leg[-1].y) == pytest.approx((1.0, 0.5))
    assert cut_path(L, 3.0) == L and cut_path(L, 5.0) == L  # no pose doubled at the end


def test_first_leg_goes_to_a_way_point_and_says_when_it_is_the_last():
    leg, final = first_leg(L, 0.5)
    assert leg == L[:2] and not final
    assert first_leg(L, 2.5) == (L, False)  # every way-point, yet not called the last leg
    assert first_leg(L, 2.5, final_slack=1.25) == (L, True)  # 3 m is within 1.25 x 2.5 m: one last leg
