"""One row of facts per robot type, read by everything that names robot types.

- `body`: the module of its simulated body (robots/), which holds `SPEC`, a robots.spec.RobotSpec
  (kinematics, cameras, sensors, postures, failure modes); robots/bodies.py loads it;
- `body_radius_m`: the body's collision cylinder in the simulator (the body's SPEC takes it from here);
- `clearance_radius_m`: the footprint the path planner keeps free round the robot
  (agents/services/navigation.py inflates the map by it): not the body, but what its collision
  protection needs to stay quiet beside a wall. The NAO's sonars look 10-40 deg to each side and stop
  it for an echo within 0.35 m, so a wall beside it must stay 0.29 m away (4 deg of heading error),
  plus its 2 cm sway and 4 cm of a leg's slip: 0.35 m. The Elektron's laser stops it only for what is
  ahead: its body and 4 cm, 0.30 m (tests/services/test_navigation.py walks both beside a wall).
  The generated houses guarantee a passage for the widest (robots/house_gen.py NAV_RADIUS);
- `odometry`: how wrong its odometry may be, as a RApp's pose filter assumes it (rapps/sdk/ekf.py
  ODOMETRY); deliberately generous: a filter that trusts its prediction too much refuses good fixes;
- `paper_localization_m`, `paper_tracking_m`: paper 001 sec. 4's figures for this robot (None: the
  paper had no such robot). The hazard table judges runs by them; the hazard RApp plans legs within
  half the tracking figure.

Derived from this table: the manifest's and the Store's known robot types (ontology/manifest.py), the
simulated bodies (robots/bodies.py, robots/world.py), the generated houses' start poses and passages
(robots/house_gen.py), the planner's radii, the EKF's odometry models and every CLI `--robot` choice.
Adding a robot type is one row here plus its body module (docs/architecture.md "Adding a robot type");
tests/test_robot_types.py checks the table against its readers and runs a RApp on a third type.
`python -m ontology.robot_types` prints the table.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple


@dataclass(frozen=True)
class Odometry:
    """1 sigma of a robot's odometry error: random parts grow with the square root of the motion,
    systematic parts (slip, drift) with the motion itself. rapps.sdk.ekf.OdometryModel adds its
    covariance."""

    trans_std: float  # m per sqrt(m) travelled
    trans_rel: float  # fraction of the distance (systematic slip)
    rot_std: float  # rad per sqrt(rad) turned
    rot_rel: float  # fraction of the turn (systematic slip)
    heading_std: float  # rad per sqrt(m) travelled
    heading_drift: float  # rad per m travelled (systematic)


class RobotType(NamedTuple):
    body: str
    body_radius_m: float
    clearance_radius_m: float
    odometry: Odometry
    description: str = ""
    paper_localization_m: float | None = None
    paper_tracking_m: float | None = None


ROBOT_TYPES: dict[str, RobotType] = {
    # the NAO's walk slips far more than the Elektron's wheels
    "nao": RobotType("robots.nao", body_radius_m=0.17, clearance_radius_m=0.35,
                     odometry=Odometry(trans_std=0.02, trans_rel=0.05, rot_std=0.05, rot_rel=0.05,
                                       heading_std=0.08, heading_drift=0.05),
                     description="NAO-like humanoid: holonomic walk, two head cameras, sonars, speech",
                     paper_localization_m=0.10, paper_tracking_m=0.20),
    "elektron": RobotType("robots.elektron", body_radius_m=0.26, clearance_radius_m=0.30,
                          odometry=Odometry(trans_std=0.01, trans_rel=0.02, rot_std=0.03, rot_rel=0.04,
                                            heading_std=0.02, heading_drift=0.05),
                          description="Elektron-like base: differential drive, pan-tilt camera, laser, no speech",
                          paper_localization_m=0.07, paper_tracking_m=0.15),
}


class UnknownRobotType(KeyError):
    """A robot type the table does not hold; the message lists the known ones."""

    def __str__(self) -> str:  # KeyError's own repr-quotes the message
        return str(self.args[0])


def robot_type(name: str) -> RobotType:
    """The facts of a robot type; UnknownRobotType (a KeyError) naming the known ones otherwise."""
    try:
        return ROBOT_TYPES[name]
    except KeyError:
        raise UnknownRobotType(f"unknown robot type {name!r} (known: {', '.join(ROBOT_TYPES)})") from None


def names() -> tuple[str, ...]:
    """The robot types in the table's order (CLI choices, runs over every robot)."""
    return tuple(ROBOT_TYPES)


def widest_clearance_m() -> float:
    """The largest clearance radius: the passage a house must leave for every robot type."""
    return max(t.clearance_radius_m for t in ROBOT_TYPES.values())


def markdown_table() -> str:
    """The table as docs/architecture.md shows it."""
    rows = ["| type | body | body radius (m) | clearance radius (m) | odometry (trans, rot, heading std) |",
            "|---|---|---:|---:|---|"]
    rows += [f"| `{name}` | `{t.body}` | {t.body_radius_m:.2f} | {t.clearance_radius_m:.2f} | {o.trans_std:g} m/√m, "
             f"{o.rot_std:g} rad/√rad, {o.heading_std:g} rad/√m |" for name, t in ROBOT_TYPES.items() for o in [t.odometry]]
    return "\n".join(rows)


if __name__ == "__main__":
    print(markdown_table())
