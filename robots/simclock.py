"""Simulation clock: fixed step, real-time factor pacing (rtf 0 = as fast as possible)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

STEP_S = 1 / 60  # a World's step unless told otherwise


@dataclass
class SimClock:
    step: float = STEP_S
    rtf: float = 0.0
    time: float = 0.0
    _wall0: float = field(default=0.0, repr=False)
    _sim0: float = field(default=0.0, repr=False)

    def restart_pacing(self) -> None:
        self._wall0, self._sim0 = time.perf_counter(), self.time

    def chunk_steps(self, max_steps: int = 30) -> int:
        """Steps to run in one worker call: many when unpaced, ~20 ms of wall time when paced."""
        if self.rtf <= 0:
            return max_steps
        return max(1, min(max_steps, round(self.rtf * 0.02 / self.step)))

    def delay(self) -> float:
        """Wall seconds to wait so that simulation time does not run ahead of rtf * wall time."""
        if self.rtf <= 0:
            return 0.0
        d = self._wall0 + (self.time - self._sim0) / self.rtf - time.perf_counter()
        if d < -0.25:  # fell behind (slow machine): do not try to catch up in a burst
            self.restart_pacing()
            return 0.0
        return max(d, 0.0)
