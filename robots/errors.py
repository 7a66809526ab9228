"""Typed errors of the simulated robots; the Core turns them into FIPA failure/refuse replies."""
from __future__ import annotations


class RobotError(Exception):
    """Base of every robot-side error. `code` is a short machine-readable tag."""

    code = "robot_error"

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message


class UnsupportedOperation(RobotError):
    """The robot's hardware cannot do this (e.g. lateral velocity on a differential drive)."""

    code = "unsupported"


class InvalidArgument(RobotError):
    """Unknown joint, camera, posture, resolution or an out-of-range value."""

    code = "invalid_argument"


class MotionBlocked(RobotError):
    """An obstacle stopped the base before the motion finished."""

    code = "blocked"


class MotionInterrupted(RobotError):
    """The motion was pre-empted by move_stop, rest or a newer motion command."""

    code = "interrupted"


class WorldClosed(RobotError):
    """The world was closed while the call was pending."""

    code = "world_closed"
