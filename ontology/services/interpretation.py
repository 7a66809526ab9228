"""Command interpretation: free text -> the RApp to run and its parameters."""
from __future__ import annotations

from pydantic import Field

from ..platform import ServiceRequest
from ..registry import Content, action


class RAppDescription(Content):
    name: str
    keywords: list[str] = []
    phrases: list[str] = []
    robot_types: list[str] = []  # empty = any robot


class Interpretation(Content):
    rapp: str
    parameters: dict[str, str] = {}
    score: float
    matched: list[str] = []


@action("interpret_command", ontology="platform", reply=Interpretation, group="speech", idempotent=True)
class InterpretCommand(ServiceRequest):
    """Which RApp a spoken or typed command asks for, with its parameters' values."""

    text: str = Field(min_length=1, max_length=1000)
    robot_type: str = ""
    rapps: list[RAppDescription] = Field(min_length=1)
