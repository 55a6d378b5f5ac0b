"""The campaign's progress table and summary line."""

from __future__ import annotations

from rich.console import Console

from acl3d.campaign.progress import ProgressView, status_table
from acl3d.campaign.run_state import RunState


def state(name: str, status: str, steps: int, total: int = 10_000) -> RunState:
    return RunState(name, status, steps, total, 0, None, 12.0, mean_rate=None)


def rendered(table) -> str:
    console = Console(width=200, record=True)
    console.print(table)
    return console.export_text()


def test_a_run_past_its_budget_reads_100_percent():
    """A run trains to whole rollouts: 12,288 steps for a budget of 10,000 is done, not 123%."""
    text = rendered(status_table([state("a", "finished", 12_288), state("b", "running", 2_500)]))
    assert "100%" in text and "123%" not in text and "25%" in text


def test_the_summary_of_a_finished_campaign_has_no_eta_to_guess(monkeypatch, capsys):
    view = ProgressView.__new__(ProgressView)
    done = [state("a", "finished", 12_288), state("b", "finished", 10_240)]
    line = view.headline(done, {})
    assert line.startswith("2/2 finished") and "ETA none left" in line
    waiting = view.headline([state("a", "finished", 10_000), state("b", "pending", 0)], {})
    assert "ETA ?" in waiting  # a run left and no rate measured yet


def test_closing_a_log_view_does_not_repeat_its_last_line(tmp_path, capsys, monkeypatch):
    states = [state("a", "finished", 10_000)]
    monkeypatch.setattr("acl3d.campaign.progress.read_states", lambda camp, runs: states)
    view = ProgressView(camp=None, runs=[], live=False)
    view.close()
    lines = [line for line in capsys.readouterr().out.splitlines() if "finished" in line]
    assert len(lines) == 1
