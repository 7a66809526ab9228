"""The one exception service implementations raise; the Platform Agent turns it into a FIPA failure."""
from __future__ import annotations

from ontology.errors import ErrorCode


class ServiceError(Exception):
    """A request the service cannot satisfy. `reason` is meant for a human; `code` is a short tag."""

    def __init__(self, reason: str, code: str = ErrorCode.SERVICE_ERROR) -> None:
        super().__init__(reason)
        self.reason = reason
        self.code = code

    def __repr__(self) -> str:
        return f"ServiceError({self.reason!r}, code={self.code!r})"
