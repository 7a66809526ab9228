"""Typed errors of the simulated robots; the Core turns them into FIPA failure/refuse replies."""
from __future__ import annotations

from ontology.errors import ErrorCode


class RobotError(Exception):
    """Base of every robot-side error. `code` is a short machine-readable tag."""

    code = ErrorCode.ROBOT_ERROR

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message


class UnsupportedOperation(RobotError):
    """The robot's hardware cannot do this (e.g. lateral velocity on a differential drive)."""

    code = ErrorCode.UNSUPPORTED


class InvalidArgument(RobotError):
    """Unknown joint, camera, posture, resolution or an out-of-range value."""

    code = ErrorCode.INVALID_ARGUMENT


class MotionBlocked(RobotError):
    """An obstacle stopped the base before the motion finished."""

    code = ErrorCode.BLOCKED


class MotionInterrupted(RobotError):
    """The motion was pre-empted by move_stop, rest or a newer motion command."""

    code = ErrorCode.INTERRUPTED


class WorldClosed(RobotError):
    """The world was closed while the call was pending."""

    code = ErrorCode.WORLD_CLOSED
