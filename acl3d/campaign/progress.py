"""The live progress of a campaign: done / running / failed, steps/s and ETA.

On a terminal it is a rich table redrawn in place; in a log file (nohup, a batch job) it is one
summary line a minute. `status_table` is the same table for `acl3d campaign status`.
"""

from __future__ import annotations

import sys
import time
from datetime import timedelta

from rich.console import Console
from rich.live import Live
from rich.table import Table

from acl3d.campaign.run_state import RunState, read_state

_REFRESH_S = 2.0
_LOG_EVERY_S = 60.0
_MAX_ROWS = 30


def read_states(camp, runs) -> list[RunState]:
    return [read_state(camp.run_dir(r.name), int(r.options["steps"])) for r in runs]


def summarize(states: list[RunState]) -> dict[str, int]:
    counts = {"finished": 0, "running": 0, "failed": 0, "pending": 0}
    for s in states:
        if s.status == "finished":
            counts["finished"] += 1
        elif s.status == "running":
            counts["running"] += 1
        elif s.status == "crashed" or s.failures:
            counts["failed"] += 1
        else:  # pending, interrupted
            counts["pending"] += 1
    return counts


def status_table(states: list[RunState], rates: dict[str, float] | None = None, title="") -> Table:
    table = Table(title=title or None)
    for col in ("run", "status", "steps", "done", "steps/s", "% mastered", "failures"):
        table.add_column(col, justify="left" if col in ("run", "status") else "right")
    shown = [s for s in states if s.status != "pending"] if len(states) > _MAX_ROWS else states
    order = {"running": 0, "crashed": 1, "interrupted": 2, "finished": 3, "pending": 4}
    for s in sorted(shown, key=lambda s: order.get(s.status, 5))[:_MAX_ROWS]:
        rate = (rates or {}).get(s.name) or s.mean_rate
        table.add_row(
            s.name,
            s.status,
            f"{s.steps:,}",
            # a run trains to whole rollouts, a few steps past its budget: 100% at the most
            f"{min(100, 100 * s.steps // max(1, s.total_steps))}%",
            f"{rate:,.0f}" if rate else "",
            "" if s.last_mastered_pct is None else f"{s.last_mastered_pct:.1f}",
            str(s.failures or ""),
        )
    return table


class ProgressView:
    def __init__(self, camp, runs, live: bool | None = None):
        self.camp, self.runs = camp, runs
        self.console = Console(file=sys.stdout)
        self.live_mode = self.console.is_terminal if live is None else live
        self._live = Live(console=self.console, auto_refresh=False) if self.live_mode else None
        if self._live is not None:
            self._live.start()
        self._first: dict[str, tuple[float, int]] = {}  # run -> (time, steps) first seen running
        self._last_draw = self._last_log = 0.0
        self._last_line = ""
        self.refresh(force=True)

    def note(self, text: str) -> None:
        self.console.print(f"[campaign] {text}", highlight=False)

    def _rates(self, states: list[RunState]) -> dict[str, float]:
        now, rates = time.monotonic(), {}
        for s in states:
            if s.status != "running":
                self._first.pop(s.name, None)
                continue
            t0, steps0 = self._first.setdefault(s.name, (now, s.steps))
            if now - t0 > 5 and s.steps > steps0:
                rates[s.name] = (s.steps - steps0) / (now - t0)
        return rates

    def headline(self, states: list[RunState], rates: dict[str, float]) -> str:
        c = summarize(states)
        total_rate = sum(rates.values())
        left = sum(max(0, s.total_steps - s.steps) for s in states if s.status != "finished")
        eta = str(timedelta(seconds=int(left / total_rate))) if total_rate > 0 else "?"
        if left == 0:
            eta = "none left"
        return (
            f"{c['finished']}/{len(states)} finished, {c['running']} running, {c['failed']} "
            f"failed, {c['pending']} waiting | {total_rate:,.0f} steps/s | ETA {eta}"
        )

    def refresh(self, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last_draw < _REFRESH_S:
            return
        self._last_draw = now
        states = read_states(self.camp, self.runs)
        rates = self._rates(states)
        line = self.headline(states, rates)
        if self._live is not None:
            self._live.update(status_table(states, rates, title=line), refresh=True)
        elif (force and line != self._last_line) or now - self._last_log >= _LOG_EVERY_S:
            self._last_log, self._last_line = now, line
            self.note(f"{time.strftime('%H:%M:%S')} {line}")

    def close(self) -> None:
        self.refresh(force=True)
        if self._live is not None:
            self._live.stop()
