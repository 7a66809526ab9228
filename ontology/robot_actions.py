"""One row of facts per robot-API action (ontology "robot"), read by everything that needs them.

- `group`: the robot-API group a RApp's manifest must declare to use the action (the Core refuses
  the others); "resources" are the lock commands, served by the Core itself, never by the robot;
- `device`: the device whose lock the Core holds while the command runs (agents/locks.py), None
  for commands that need no exclusive use;
- `motion`: it moves something, so the Core holds it while the emergency stop is latched;
- `idempotent`: a read without side effects, sent again after a timeout (agents/base.py `request`);
- `drive`: its effect on the base's velocity after the call returns, watched by the Core's safety
  monitor: "sets" (move_vel: driving while the velocity is not zero), "ends" (no velocity in force
  afterwards), None (no effect);
- `core`: served by the Core itself, never by the robot (the locks; the Core's pose estimate,
  agents/core_localizer.py).

ontology/robot.py registers each action with the group and idempotency of its row;
docs/architecture-actions.md shows this table (`python -m ontology.robot_actions` prints it) and
tests/test_action_facts.py checks both against it.
"""
from __future__ import annotations

from typing import Literal, NamedTuple

# the devices a RApp may lock (lock_resource / free_resource) and the robot-API commands take
DEVICES = ("base", "head", "joints", "camera", "speaker", "microphone")


class ActionFacts(NamedTuple):
    group: str
    device: str | None = None
    motion: bool = False
    idempotent: bool = False
    drive: Literal["sets", "ends"] | None = None
    core: bool = False


F = ActionFacts
ACTION_FACTS: dict[str, ActionFacts] = {
    # action                     group            device        motion  idempotent drive  core
    "say":                     F("communication", "speaker",    False, False),
    "word_spotting":           F("communication", "microphone", False, False),
    "capture_audio":           F("communication", "microphone", False, True),
    "play_audio":              F("communication", "speaker",    False, False),
    "microphone_energy":       F("communication", "microphone", False, True),
    "capture_image":           F("vision",        "camera",     False, True),
    "set_camera_param":        F("vision",        "camera",     False, False),
    "set_camera_params":       F("vision",        "camera",     False, False),
    "get_camera_info":         F("vision",        None,         False, True),
    "capture_depth":           F("vision",        None,         False, True),
    "move_to":                 F("navigation",    "base",       True,  False, "ends"),
    "move_vel":                F("navigation",    "base",       True,  False, "sets"),
    "move_stop":               F("navigation",    None,         False, False, "ends"),
    "move_along_path":         F("navigation",    "base",       True,  False, "ends"),
    "look_at_point":           F("navigation",    "head",       True,  False),
    "get_global_pose":         F("navigation",    None,         False, True),
    "get_pose_estimate":       F("navigation",    None,         False, True,  None,  True),
    "add_pose_fix":            F("navigation",    None,         False, False, None,  True),
    "set_global_pose":         F("navigation",    None,         False, False),
    "get_transform":           F("navigation",    None,         False, True),
    "move_joint":              F("navigation",    "joints",     True,  False),
    "get_joint_angles":        F("navigation",    None,         False, True),
    "take_predefined_posture": F("navigation",    "joints",     True,  False),
    "rest":                    F("navigation",    "joints",     True,  False),
    "get_sonars":              F("sensors",       None,         False, True),
    "get_laser_scan":          F("sensors",       None,         False, True),
    "get_contacts":            F("sensors",       None,         False, True),
    "lock_resource":           F("resources",     None,         False, False, None,  True),
    "free_resource":           F("resources",     None,         False, False, None,  True),
}
del F

# the groups a manifest may declare in robot_api ("resources" needs no declaration)
ROBOT_API_GROUPS = frozenset(f.group for f in ACTION_FACTS.values()) - {"resources"}


def facts(name: str) -> ActionFacts:
    """The facts of a robot action; KeyError for a name that is not one."""
    return ACTION_FACTS[name]


# motions whose target is relative to where the robot is (or a velocity): after an emergency stop
# interrupted them, issuing them again would go somewhere else, so the Core does not resume them
RELATIVE_MOTIONS = frozenset({"move_to", "move_vel"})


def resumable(name: str) -> bool:
    """A motion the emergency stop interrupts is issued again after the resume (absolute target)."""
    return facts(name).motion and name not in RELATIVE_MOTIONS


def markdown_table() -> str:
    """The table as docs/architecture-actions.md shows it."""
    def cell(v: object) -> str:
        return "yes" if v is True else "no" if v is False else "–" if v is None else f"`{v}`"

    rows = ["| action | group | device | motion | idempotent | drive | served by the Core |",
            "|---|---|---|---|---|---|---|"]
    rows += [f"| `{name}` | " + " | ".join(cell(v) for v in f) + " |" for name, f in ACTION_FACTS.items()]
    return "\n".join(rows)


if __name__ == "__main__":
    print(markdown_table())
