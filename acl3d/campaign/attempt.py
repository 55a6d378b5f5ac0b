"""One attempt at one run, executed inside a worker (a Ray task or a local child process).

The attempt decides from the run directory what to do: a finished run is left alone, a run with
a complete checkpoint is resumed from it (`train(resume=...)`), anything else starts afresh in
a cleared directory (its campaign log and earlier failures are kept). A Python failure leaves
its traceback in `failures/attempt_K.txt` and returns `ok=False` (with `retry=False` when train
rejected the config before creating the run: retrying cannot help); an interrupt propagates.
An attempt never runs beside another process working in the same run directory.
"""

from __future__ import annotations

import os
import socket
import time
import traceback
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

from acl3d.campaign.lock import directory_busy, try_lock
from acl3d.campaign.run_state import LOG_NAME, read_state, record_failure

# An attempt of a stopped campaign ends within seconds (SIGTERM: train writes its status).
WAIT_FOR_HOLDER_S = 120.0
_POLL_S = 0.2


def run_attempt(
    run_dir: str,
    options: dict,
    cpus: int,
    wait_s: float = WAIT_FOR_HOLDER_S,
    where: str | None = None,
) -> dict:
    """Train (or resume) the run in `run_dir` with `options`, on `cpus` torch threads; `where`
    (e.g. the Ray node) is added to the host and pid the run's log names for the attempt.

    Nothing starts while another process works in the run directory (the attempt of a campaign
    process that was killed, still ending; a training started by hand): the attempt waits up to
    `wait_s` seconds for it to end, then gives up without touching the run (`retry=False`).
    """
    import acl3d
    from acl3d.training import train

    run = Path(run_dir)
    run.mkdir(parents=True, exist_ok=True)
    runtime = {"progress_bar": False, "torch_threads": int(cpus)}
    with (run / LOG_NAME).open("a", buffering=1) as log, redirect_stdout(log), redirect_stderr(log):
        stamp = f"{socket.gethostname()} pid {os.getpid()}" + (f" {where}" if where else "")
        busy = _wait_until_free(run, log.fileno(), wait_s, stamp)
        if busy is not None:
            error = f"{busy} still works in {str(run)!r} after {wait_s:g} s: not started"
            print(f"[campaign] {_now()} {stamp}: {error}", flush=True)
            return {"ok": False, "error": error, "retry": False}
        state = read_state(run, int(options["steps"]))
        what = (
            "already finished"
            if state.finished
            else f"resuming from its step-{state.checkpoint_step} checkpoint"
            if state.resumable
            else "starting afresh"
        )
        print(
            f"[campaign] {_now()} {stamp}: {what}; acl3d imported from {acl3d.__file__}",
            flush=True,
        )
        if state.finished:
            return {"ok": True, "steps": state.steps}
        try:
            if state.resumable:
                result = train(resume=run, steps=int(options["steps"]), **runtime)
            else:  # a new run in place of any partial one (its log and failures are kept)
                result = train({**options, **runtime, "out": str(run)}, overwrite=True)
        except Exception as exc:
            text = traceback.format_exc()
            print(text, flush=True)
            record_failure(run, text)
            # train checks the whole config before it creates the run: nothing to retry then
            retry = (run / "config.yaml").exists()
            return {"ok": False, "error": f"{type(exc).__name__}: {exc}", "retry": retry}
    return {"ok": True, "steps": int(result.steps)}


def _wait_until_free(run: Path, log_fd: int, wait_s: float, stamp: str) -> str | None:
    """Take the lock of the run's campaign log (held until the attempt ends) and wait until no
    training process holds the run directory's; None once both are ours / free, else who has
    one of them after `wait_s` seconds."""
    deadline = time.monotonic() + wait_s
    said = False
    while True:
        if not try_lock(log_fd):
            busy = "another attempt of this run (of a campaign process that was stopped?)"
        elif directory_busy(run):
            busy = "another training process"
        else:
            return None
        if time.monotonic() >= deadline:
            return busy
        if not said:
            print(f"[campaign] {_now()} {stamp}: waiting for {busy} to end", flush=True)
            said = True
        time.sleep(_POLL_S)


def _now() -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S")
