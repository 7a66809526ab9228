"""Replies shared by every ontology: FIPA error performatives carry one of these."""
from __future__ import annotations

from .errors import ErrorCode
from .registry import Content


class Reason(Content):
    """Content of refuse, failure and not-understood: a human-readable reason and a short code."""

    reason: str
    code: str = ErrorCode.ERROR

