"""Item 11: a run directory damaged as a crash or a hand edit would (torn logs, a stale
LATEST, a dead process's 'running', an edited JSON, a truncated model), on copies of the
reference run."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from safety_probe.kit import (
    Check,
    Probe,
    campaign_args,
    item,
    no_traceback,
    refused,
    snapshot,
    status,
    truncate,
    unchanged,
)

LAST, FIRST = "step_000000000512", "step_000000000256"


RESUME_WRITES = (
    "status.json", "config.yaml", "config.json", "provenance.json", "checkpoints/LATEST",
    "final_model", "tb/",
)  # fmt: skip


def dead_pid() -> int:
    """The pid of a process that has ended (and been reaped)."""
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    return gone.pid


def crashed_run(probe: Probe) -> Path:
    """A copy of the finished run as a SIGKILL before the final save leaves it: no final model,
    status.json still 'running' for a process that has ended."""
    run = probe.finished_run()
    for final in run.glob("final_model*"):
        final.unlink()
    doc = {**json.loads((run / "status.json").read_text()), "status": "running", "pid": dead_pid()}
    (run / "status.json").write_text(json.dumps(doc))
    return run


def edit_rng_pos(checkpoint: Path) -> None:
    """`"pos": 119` -> `"pos": 3119` in rng.json: still valid JSON, another random stream."""
    rng = checkpoint / "rng.json"
    rng.write_text(rng.read_text().replace('"pos": ', '"pos": 3', 1))


def analysed(folder: Path) -> dict[str, str]:
    """Run name -> status, as `acl3d analyze` wrote them in its report's evaluations.csv."""
    table = folder / "report" / "evaluations.csv"
    rows = table.read_text().splitlines()[1:] if table.exists() else []
    return {Path(r.split(",")[0]).name: r.split(",")[1] for r in rows}  # NAME or runs/NAME


def eval_rows(run: Path) -> list[str]:
    """evals.csv without its wall-time column."""
    return [row.rsplit(",", 1)[0] for row in (run / "evals.csv").read_text().splitlines()]


def torn_logs(probe: Probe) -> list[Check]:
    folder = probe.path("analyze")
    folder.mkdir()
    for name in ("good", "torn", "noevals"):
        probe.finished_run().rename(folder / name)
    with (folder / "torn" / "evals.csv").open("a") as evals:
        evals.write("4096,82")  # a row cut by a kill
    (folder / "noevals" / "evals.csv").unlink()
    before = snapshot(folder)
    proc = probe.acl3d("analyze", folder, "--reps", "100", timeout=120)
    torn, missing = folder / "torn" / "evals.csv", folder / "noevals" / "evals.csv"
    return [
        no_traceback(proc, "analyze, a torn row and a missing evals.csv: exit 0", want_rc=0),
        Check(
            "... the torn run is named with its file and skipped",
            f"skipping run torn: {torn} line 4 is torn" in proc.stderr,
            proc.stderr[:160],
        ),
        Check(
            "... the run without evals.csv is named and skipped",
            f"skipping run noevals: {missing} is missing" in proc.stderr,
        ),
        Check("... the other run is analysed", list(analysed(folder)) == ["good"]),
        unchanged(before, folder, "... nothing lost (only report/ written)", ("report/",)),
    ]


def stale_latest(probe: Probe) -> list[Check]:
    checks = []
    for latest, says in (("", "is empty"), ("step_000000000128", "which is not there")):
        run = crashed_run(probe)
        (run / "checkpoints" / "LATEST").write_text(latest)
        before = snapshot(run)
        proc = probe.acl3d("train", "--resume", run, timeout=300)
        checks += [
            no_traceback(proc, f"LATEST {latest or 'empty'}: resume, exit 0", want_rc=0, says=says),
            Check(
                "... from the newest checkpoint, no advice to delete",
                "using the newest checkpoint" in proc.stderr
                and "--overwrite" not in proc.stderr
                and (run / "checkpoints" / "LATEST").read_text() == LAST
                and status(run) == "finished",
                proc.stderr.strip()[-160:],
            ),
            unchanged(before, run, "... nothing lost, nothing retrained", RESUME_WRITES),
        ]
    return checks


def dead_process(probe: Probe) -> list[Check]:
    camp = probe.path("campaign")
    proc = probe.acl3d(*campaign_args(camp, 256, "--executor", "local"), timeout=300)
    if proc.returncode != 0:
        return [Check("a tiny campaign trains", False, proc.stderr[-160:])]
    killed = sorted(camp.glob("runs/*"))[0]
    doc = json.loads((killed / "status.json").read_text())
    (killed / "status.json").write_text(json.dumps({**doc, "status": "running", "pid": dead_pid()}))
    before = snapshot(camp)
    shown = probe.acl3d("campaign", "status", camp, timeout=60)
    row = next((line for line in shown.stdout.splitlines() if killed.name in line), "")
    proc = probe.acl3d("analyze", camp, "--reps", "100", timeout=120)
    return [
        no_traceback(shown, "campaign status, 'running' with a dead pid: exit 0", want_rc=0),
        Check(
            "... shows the run crashed, counted as failed",
            "crashed" in row and "1 failed" in shown.stdout,
            shown.stdout.strip()[:160],
        ),
        no_traceback(proc, "analyze of that campaign: exit 0", want_rc=0),
        Check(
            "... lists the run as crashed",
            analysed(camp).get(killed.name) == "crashed",
            str(analysed(camp)),
        ),
        unchanged(before, camp, "... nothing lost (only report/ written)", ("report/",)),
    ]


def edited_json(probe: Probe) -> list[Check]:
    run = crashed_run(probe)
    edit_rng_pos(run / "checkpoints" / LAST)
    before = snapshot(run)
    proc = probe.acl3d("train", "--resume", run, timeout=300)
    damaged = {
        key.split("/", 2)[2]: data
        for key, data in before.items()
        if key.startswith(f"checkpoints/{LAST}/")
    }
    weights = probe.same_weights(probe.reference(), run)
    checks = [
        no_traceback(proc, "rng.json 'pos' edited: resume, exit 0", want_rc=0),
        Check(
            f"... {LAST} refused by name, by its manifest hash",
            f"skipping damaged checkpoint {LAST}" in proc.stderr
            and "rng.json differs from the checkpoint's manifest.json" in proc.stderr,
            proc.stderr.strip()[-160:],
        ),
        Check(
            "... the edited checkpoint is set aside whole",
            snapshot(run / "checkpoints" / f".damaged_{LAST}") == damaged,
        ),
        Check(
            "... retrained from step 256 to the uninterrupted run's result",
            eval_rows(run) == eval_rows(probe.reference())
            and weights.stdout.strip() == "True"
            and status(run) == "finished",
            weights.stderr[-160:],
        ),
        unchanged(
            before,
            run,
            "... nothing else changed",
            RESUME_WRITES + ("evals.csv", f"checkpoints/{LAST}/", f"checkpoints/.damaged_{LAST}/"),
        ),  # fmt: skip
    ]
    run = crashed_run(probe)
    for checkpoint in (run / "checkpoints").glob("step_*"):
        edit_rng_pos(checkpoint)
    before = snapshot(run)
    proc = probe.acl3d("train", "--resume", run, timeout=120)
    checks.append(refused(proc, "no complete checkpoint", "every rng.json edited: refused"))
    checks.append(unchanged(before, run, "... nothing changed"))
    return checks


def evaluate_crashed(probe: Probe) -> list[Check]:
    run = crashed_run(probe)
    truncate(run / "checkpoints" / LAST / "model.zip")
    before = snapshot(run)
    proc = probe.acl3d("evaluate", run, timeout=300)
    first = run / "checkpoints" / FIRST / "model.zip"
    return [
        no_traceback(proc, "evaluate, crashed run, latest model.zip truncated: exit 0", want_rc=0),
        Check(
            "... says it skips the damaged checkpoint, evaluates step 256",
            f"skipping damaged checkpoint {LAST}" in proc.stderr
            and f"evaluating {first} (step 256)" in proc.stdout,
            (proc.stderr + proc.stdout)[:160],
        ),
        unchanged(before, run, "... nothing changed in the run"),
    ]


@item(11, "run-directory faults: torn logs, stale LATEST, dead process, edited JSON, evaluate")
def run_directory_faults(probe: Probe) -> list[Check]:
    """Issue items 3, 8, 9, 10 and 11, each on copies of the reference run; 'crashed' is how a
    SIGKILL before the final save leaves a run."""
    stories = (torn_logs, stale_latest, dead_process, edited_json, evaluate_crashed)
    return [check for story in stories for check in story(probe)]
