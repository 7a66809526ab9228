"""The simulated body of each robot type: the `SPEC` (robots.spec.RobotSpec) of the module that
ontology/robot_types.py names for it. Bodies load on first use and are read through the table each
time, so a row added at run time (a test's third robot type) has its body here too."""
from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping

from ontology.robot_types import ROBOT_TYPES, robot_type

from .spec import RobotSpec


def spec(kind: str) -> RobotSpec:
    """The body of robot type `kind`; UnknownRobotType (a KeyError) for a type not in the table."""
    facts = robot_type(kind)
    body = importlib.import_module(facts.body).SPEC
    if body.kind != kind or body.radius != facts.body_radius_m:  # a body copied from another type's
        raise ValueError(f"{facts.body}.SPEC is a {body.kind!r} body of radius {body.radius} m, but the robot "
                         f"type table says {kind!r}, {facts.body_radius_m} m")
    return body


class _Specs(Mapping[str, RobotSpec]):
    """Every type's body, as a mapping (robots.ROBOT_SPECS)."""

    def __getitem__(self, kind: str) -> RobotSpec:
        return spec(kind)

    def __iter__(self) -> Iterator[str]:
        return iter(ROBOT_TYPES)

    def __len__(self) -> int:
        return len(ROBOT_TYPES)


ROBOT_SPECS: Mapping[str, RobotSpec] = _Specs()
