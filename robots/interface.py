"""What a Core needs from its robot, as a typed Protocol: the simulated RobotAPI implements it, and
so must a driver of a real robot (or a test's wrapper). The Core checks it once, at construction,
instead of probing attributes while it runs."""
from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

# What a RApp may ask its runtime about (ontology.spawn.RobotInfo.capabilities)
CAPABILITIES = ("speech", "microphone", "camera", "head", "sonars", "laser", "depth", "bumpers", "touch")


@runtime_checkable
class Microphone(Protocol):
    async def listen(self, timeout: float) -> str | None:
        """The next utterance heard (text), or None when nothing was heard within `timeout` s."""


class LoudspeakerTiming(Protocol):
    """When the robot's own voice sounds, on the clock of its microphone's sound (CaptureAudio.stamp)."""

    def now(self) -> float:
        """That clock's time now."""

    def sounding_until(self, t0: float, t1: float, tail: float = 0.0) -> float | None:
        """When the loudspeaker's sound within [t0, t1] ends (+ `tail`, e.g. its way to a microphone),
        or None: silent then."""


@runtime_checkable
class RobotInterface(Protocol):
    async def handle(self, req) -> Any:
        """Carry out one ontology.robot request model; return its reply model or raise
        robots.errors.RobotError (InvalidArgument, UnsupportedOperation, MotionInterrupted...)."""

    def moving_forward(self, min_speed: float = 0.02) -> bool:
        """A base motion runs forward now: what the Core's forward-range safety check watches."""

    def capabilities(self) -> frozenset[str]:
        """The subset of CAPABILITIES this robot has."""

    async def halt(self, reason: str) -> None:
        """Every effector stops now (base, head, joints, loudspeaker): the emergency stop."""

    def protect(self, margin_m: float | None) -> None:
        """The robot's own collision protection: a base motion driving forward stops (MotionBlocked)
        when a range reading ahead (±30°) comes within `margin_m` of the sensor's minimum range;
        None turns it off. A real robot's driver maps it to its own (NAO: ALMotion's external
        collision protection; a laser scanner's protective field); the simulation checks every 50 ms
        of simulated time, however fast the world runs."""

    @property
    def microphone(self) -> Microphone | None:
        """Where the owner's spoken commands are heard, or None (chat only)."""

    def odometry_counters(self) -> tuple[float, float]:
        """How far the base has moved and turned in all (m, rad), as its odometry counts them (wheel
        encoders, a walk's steps): between two reads of the pose, the motion made, which may be much
        longer than the displacement (legs with corners, a turn and back). The Core's pose estimate
        grows its uncertainty with it (agents/core_localizer.py)."""

    def loudspeaker_timing(self) -> LoudspeakerTiming | None:
        """The loudspeaker's timing where the robot can tell it (the simulation keeps what its
        loudspeaker played), so that the Core cuts the robot's own voice out of what it hears; None
        where it cannot (the Core then drops what its microphone heard while it spoke)."""


def check_robot(api: object) -> RobotInterface:
    """`api` if it implements RobotInterface; else a TypeError naming what is missing."""
    if isinstance(api, RobotInterface):
        return api
    missing = [n for n in ("handle", "moving_forward", "capabilities", "halt", "protect", "microphone",
                           "odometry_counters", "loudspeaker_timing") if not hasattr(api, n)]
    raise TypeError(f"{type(api).__name__} is not a robots.interface.RobotInterface: missing {', '.join(missing)}")
