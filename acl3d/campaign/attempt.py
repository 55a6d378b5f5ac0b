"""One attempt at one run, executed inside a worker (a Ray task or a local child process).

The attempt decides from the run directory what to do: a finished run is left alone, a run with
a complete checkpoint is resumed from it (`train(resume=...)`), anything else starts afresh in
a cleared directory (its campaign log and earlier failures are kept). A Python failure leaves
its traceback in `failures/attempt_K.txt` and returns `ok=False` (with `retry=False` when train
rejected the config before creating the run: retrying cannot help); an interrupt propagates.
"""

from __future__ import annotations

import os
import shutil
import socket
import time
import traceback
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

from acl3d.campaign.run_state import FAILURES, LOG_NAME, read_state, record_failure


def run_attempt(run_dir: str, options: dict, cpus: int) -> dict:
    """Train (or resume) the run in `run_dir` with `options`, on `cpus` torch threads."""
    import acl3d
    from acl3d.training import train

    run = Path(run_dir)
    run.mkdir(parents=True, exist_ok=True)
    state = read_state(run, int(options["steps"]))
    runtime = {"progress_bar": False, "torch_threads": int(cpus)}
    with (run / LOG_NAME).open("a", buffering=1) as log, redirect_stdout(log), redirect_stderr(log):
        what = (
            "already finished"
            if state.finished
            else f"resuming from its step-{state.checkpoint_step} checkpoint"
            if state.resumable
            else "starting afresh"
        )
        print(
            f"[campaign] {time.strftime('%Y-%m-%d %H:%M:%S')} {socket.gethostname()} "
            f"pid {os.getpid()}: {what}; acl3d imported from {acl3d.__file__}",
            flush=True,
        )
        if state.finished:
            return {"ok": True, "steps": state.steps}
        try:
            if state.resumable:
                result = train(resume=run, steps=int(options["steps"]), **runtime)
            else:
                _clear(run)
                result = train({**options, **runtime, "out": str(run)})
        except Exception as exc:
            text = traceback.format_exc()
            print(text, flush=True)
            record_failure(run, text)
            # train checks the whole config before it creates the run: nothing to retry then
            retry = (run / "config.yaml").exists()
            return {"ok": False, "error": f"{type(exc).__name__}: {exc}", "retry": retry}
    return {"ok": True, "steps": int(result.steps)}


def _clear(run: Path) -> None:
    """Remove a run's partial outputs (no usable checkpoint), keeping its log and failures."""
    for path in run.iterdir():
        if path.name in (LOG_NAME, FAILURES):
            continue
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()
