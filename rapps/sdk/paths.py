"""A planned path (a list of ontology Pose2D, as path_planning_plan_path_2d returns it) cut into legs:
a RApp walks a leg, localizes, and plans again from where it is."""
from __future__ import annotations

import math
from typing import Sequence

from ontology.services.common import Pose2D


def path_length(poses: Sequence[Pose2D]) -> float:
    """Metres along the path."""
    return sum(math.hypot(b.x - a.x, b.y - a.y) for a, b in zip(poses, poses[1:]))


def point_at(poses: Sequence[Pose2D], s: float) -> Pose2D:
    """The pose `s` metres along the path, heading along its segment there (the path's last pose beyond
    its end)."""
    run = 0.0
    for a, b in zip(poses, poses[1:]):
        d = math.hypot(b.x - a.x, b.y - a.y)
        if run + d >= s and d > 0:
            t = (s - run) / d
            return Pose2D(x=a.x + t * (b.x - a.x), y=a.y + t * (b.y - a.y), theta=math.atan2(b.y - a.y, b.x - a.x))
        run += d
    return poses[-1]


def cut_path(poses: Sequence[Pose2D], s: float) -> list[Pose2D]:
    """The path up to `s` metres along it, ending exactly there (all of it when shorter)."""
    if s >= path_length(poses):
        return list(poses)
    out, run = [poses[0]], 0.0
    for a, b in zip(poses, poses[1:]):
        run += math.hypot(b.x - a.x, b.y - a.y)
        if run >= s - 1e-6:
            break
        out.append(b)
    return out + [point_at(poses, s)]


def first_leg(poses: Sequence[Pose2D], length: float, final_slack: float = 1.0) -> tuple[list[Pose2D], bool]:
    """The path's way-points up to the first at least `length` metres along it, and whether that is the
    whole path: it is when the path is at most `final_slack` times `length` long (a last leg a little
    longer than the others, rather than a short one after it)."""
    if path_length(poses) <= final_slack * length:
        return list(poses), True
    out, run = [poses[0]], 0.0
    for a, b in zip(poses, poses[1:]):
        out.append(b)
        run += math.hypot(b.x - a.x, b.y - a.y)
        if run >= length:
            break
    return out, False
