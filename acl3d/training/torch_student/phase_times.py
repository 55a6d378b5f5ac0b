"""Where a torch-native run's wall time goes, phase by phase, so that a run says what bounds it.

Phases: `collect` (stepping the worlds and the policy's actions; on a GPU, waiting for the device
too), `teacher` (the controller learning finished episodes and drawing tasks; it runs inside
`collect`, whose figure excludes it), `update` (the PPO update), `evaluate`, and `records` (episode
log, checkpoints). The seconds go to the run's status file and, with `verbose`, to the console.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

PHASES = ("collect", "teacher", "update", "evaluate", "records")


class PhaseTimes:
    """Wall seconds spent in each phase since the process started training."""

    def __init__(self):
        self.seconds = dict.fromkeys(PHASES, 0.0)

    @contextmanager
    def phase(self, name: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - start

    def report(self) -> dict[str, float]:
        """Seconds per phase, `collect` without the teacher's share inside it."""
        seconds = dict(self.seconds)
        seconds["collect"] -= seconds["teacher"]
        return {name: round(value, 3) for name, value in seconds.items()}

    def summary(self) -> str:
        seconds = self.report()
        total = sum(seconds.values()) or 1.0
        return ", ".join(f"{k} {v:.1f} s ({100 * v / total:.1f}%)" for k, v in seconds.items())
