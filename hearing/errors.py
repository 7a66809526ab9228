"""Typed errors of hearing. Each carries a short machine-readable `code` (ontology.errors.ErrorCode):
a responder answers any exception with a `code` as a failure of that code (agents/responder.py), so
the robot's `say` and the Platform's speech services send these as they are."""
from __future__ import annotations

from ontology.errors import ErrorCode


class HearingError(Exception):
    """Base of every hearing error."""

    code: str = ErrorCode.INVALID

    def __init__(self, message: str, code: str | None = None):
        super().__init__(message)
        self.message = message
        if code is not None:
            self.code = code


class InvalidArgument(HearingError):
    """A text, voice, rate, grammar or sample rate hearing cannot take."""

    code = ErrorCode.INVALID_ARGUMENT


class SpeechUnavailable(HearingError):
    """eSpeak NG is not installed here (the `speech` extra)."""

    code = ErrorCode.UNSUPPORTED


class BadAudio(HearingError):
    """Audio that cannot be used: `code` says why (malformed, unsupported, too-large, invalid)."""

    def __init__(self, message: str, code: str = ErrorCode.INVALID):
        super().__init__(message, code)
