"""Recordings as tests (docs/sdk.md "A recording as a test"): a RApp's test replays a recorded run of
it (rapps/replay.py) against the RApp's current source and fails on the first divergence.

    from rapps.sdk.testing import assert_replays

    async def test_behaves_as_recorded():
        await assert_replays(HERE / "tests" / "recording", HERE)

Record one with `rapp run rapp DIR --out RUN`, keep what a replay needs with
`rapp replay RUN --save DIR/tests/recording` (trace, message bodies, package, result: no credentials).
Not imported by `rapps.sdk` itself: a RApp's code never needs it, only its tests.
"""
from __future__ import annotations

from pathlib import Path

from rapps.replay import RecordingError, ReplayResult, replay

__all__ = ["assert_replays", "has_recording", "RecordingError"]


def has_recording(run_dir: str | Path) -> bool:
    """A folder `rapp replay` can replay (a trace and its message bodies)."""
    d = Path(run_dir)
    return (d / "trace.jsonl").exists() and (d / "messages.jsonl").exists()


async def assert_replays(run_dir: str | Path, rapp_dir: str | Path | None = None, *, run: int | None = None,
                         stall_s: float = 10.0, timeout_s: float = 300.0, in_process: bool = True) -> ReplayResult:
    """Replay the recording's RApp run (`rapp_dir`: this source folder instead of the recorded package)
    and fail with the first divergence, both sides shown; the result when there is none.
    `in_process`: the RApp runs in the test's process (fast; your own code), else sandboxed as a Core runs it."""
    result = await replay(run_dir, rapp_dir=rapp_dir, run=run, mode="inprocess" if in_process else "process",
                          stall_s=stall_s, timeout_s=timeout_s)
    if not result.ok:
        raise AssertionError(result.summary())
    return result
