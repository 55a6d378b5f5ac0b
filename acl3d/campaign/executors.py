"""Where attempts run: Ray tasks (local instance or a cluster) or local child processes.

Both executors take jobs one at a time (`submit`) and report finished ones (`wait`); the
campaign loop above them owns queueing and retries, so both behave the same. A worker that
dies without a Python traceback (killed, out of memory, segfault) is reported as a failure
with the executor's explanation.
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass

from acl3d.extras import optional_dependency

EXECUTORS = ("ray", "local")
_SHUTDOWN_GRACE_S = 30.0
_PR_SET_PDEATHSIG = 1  # linux/prctl.h


@dataclass
class Job:
    name: str
    run_dir: str
    options: dict
    cpus: int


@dataclass
class Outcome:
    ok: bool
    error: str | None = None
    traceback: str | None = None  # set when the worker could not record one itself
    retry: bool = True


def refuse_in_worker_import() -> None:
    """A worker started with spawn or forkserver re-imports the user's main script (as
    `__mp_main__`); a script that calls `run_campaign` at top level, without an
    `if __name__ == "__main__":` guard, would start the campaign again in every worker (which
    then died on the campaign lock). Refuse that with the fix in the message.

    While the worker runs the script, `__mp_main__` is the script's module and `__main__` is
    still the worker's own (they are the same module everywhere else); once it has run, the
    worker's `__main__` is named `__mp_main__`."""
    main, script = sys.modules.get("__main__"), sys.modules.get("__mp_main__")
    importing = script is not None and script is not main
    if importing or getattr(main, "__name__", None) == "__mp_main__":
        raise RuntimeError(
            f"run_campaign was called while a campaign worker imported "
            f"{getattr(script, '__file__', 'the main script')}: put the call under "
            '`if __name__ == "__main__":` (workers re-import the script that starts them)'
        )


def check_executor(kind: str, max_parallel: int | None, address: str | None = None) -> None:
    refuse_in_worker_import()
    if kind not in EXECUTORS:
        raise ValueError(f"executor {kind!r} unknown; valid: {', '.join(EXECUTORS)}")
    if max_parallel is not None and (
        isinstance(max_parallel, bool) or not isinstance(max_parallel, int) or max_parallel < 1
    ):
        raise ValueError(f"max_parallel must be an integer >= 1, got {max_parallel!r}")
    if address is not None and kind != "ray":
        raise ValueError("address applies to the ray executor only")
    if kind == "ray":
        _ray()  # a missing [campaign] extra fails before the campaign directory is touched


def _ray():
    with optional_dependency("the ray executor"):
        import ray
    return ray


def make_executor(kind: str, max_parallel: int | None, cpus: int, address: str | None = None):
    check_executor(kind, max_parallel, address)
    if kind == "ray":
        return RayExecutor(max_parallel, cpus, address)
    return LocalExecutor(max_parallel, cpus)


# ---------------------------------------------------------------------- local processes
def _child(run_dir: str, options: dict, cpus: int, driver: int) -> None:
    from acl3d.campaign.attempt import run_attempt

    _die_with(driver)
    result = run_attempt(run_dir, options, cpus)
    sys.exit(0 if result["ok"] else 3 if result.get("retry", True) else 4)


def _die_with(driver: int) -> None:
    """SIGTERM this attempt when the campaign process `driver` dies, however it dies (SIGKILL
    included), so that no attempt outlives its campaign to race a continuing one: train ends
    like on Ctrl-C, its status written. Linux's parent-death signal; a watching thread where
    there is none."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    else:

        def watch() -> None:
            while os.getppid() == driver:
                time.sleep(1.0)
            os.kill(os.getpid(), signal.SIGTERM)

        threading.Thread(target=watch, name="acl3d-die-with-campaign", daemon=True).start()
    if os.getppid() != driver:  # it died before the signal was armed
        os.kill(os.getpid(), signal.SIGTERM)


class LocalExecutor:
    """Each attempt in a fresh `spawn` child process, at most `max_parallel` at a time; an
    attempt ends when the campaign process does (`_die_with`)."""

    def __init__(self, max_parallel: int | None, cpus: int):
        self.capacity = max_parallel or max(1, (os.cpu_count() or 1) // cpus)
        self._ctx = mp.get_context("spawn")
        self._running: dict[str, tuple[Job, mp.Process]] = {}

    def free_slots(self) -> int:
        return self.capacity - len(self._running)

    def submit(self, job: Job) -> None:
        proc = self._ctx.Process(
            target=_child,
            args=(job.run_dir, job.options, job.cpus, os.getpid()),
            name=f"acl3d-{job.name}",
        )
        proc.start()
        self._running[job.name] = (job, proc)

    def wait(self, timeout: float) -> list[tuple[Job, Outcome]]:
        from multiprocessing.connection import wait

        procs = [p.sentinel for _, p in self._running.values()]
        if procs:
            wait(procs, timeout=timeout)
        done = []
        for name, (job, proc) in list(self._running.items()):
            if proc.exitcode is None:
                continue
            proc.join()
            del self._running[name]
            if proc.exitcode == 0:
                done.append((job, Outcome(True)))
            elif proc.exitcode in (3, 4):
                why = "training failed (traceback in the run's failures/)"
                done.append((job, Outcome(False, why, retry=proc.exitcode == 3)))
            else:
                why = f"worker process exited with code {proc.exitcode}"
                if proc.exitcode < 0:
                    why = f"worker process killed by signal {-proc.exitcode}"
                done.append((job, Outcome(False, why, traceback=why + "\n")))
        return done

    def shutdown(self, interrupt: bool) -> None:
        """Stop running attempts like Ctrl-C (train marks them interrupted), then reap them."""
        if interrupt:
            for _, proc in self._running.values():
                if proc.exitcode is None:
                    os.kill(proc.pid, signal.SIGINT)
        for _, proc in self._running.values():
            proc.join(_SHUTDOWN_GRACE_S)
            if proc.exitcode is None:
                proc.kill()
                proc.join()
        self._running.clear()


# ---------------------------------------------------------------------- Ray
def _ray_attempt(run_dir: str, options: dict, cpus: int) -> dict:
    import ray

    from acl3d.campaign.attempt import run_attempt

    node = ray.get_runtime_context().get_node_id()
    return run_attempt(run_dir, options, cpus, where=f"ray node {node}")


class _TokenAuthNotice(logging.Filter):
    """Drops Ray's warning that it turned token authentication on for a new local instance:
    the secure default it announces is what a campaign wants, so the warning is only noise."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith("Token authentication is enabled")


def _quiet_token_auth_notice() -> None:
    logger = logging.getLogger("ray._private.authentication.authentication_token_setup")
    if not any(isinstance(f, _TokenAuthNotice) for f in logger.filters):
        logger.addFilter(_TokenAuthNotice())


class RayExecutor:
    """One Ray task per attempt, declaring `cpus` CPUs; a local Ray instance unless `address`."""

    def __init__(self, max_parallel: int | None, cpus: int, address: str | None):
        ray = self._ray = _ray()
        self._owns = not ray.is_initialized()
        if self._owns:
            kwargs = dict(include_dashboard=False, log_to_driver=False, logging_level="WARNING")
            if address:
                ray.init(address=address, **kwargs)
            else:  # a local instance sized to the campaign, so runs never oversubscribe it
                # Ray nices its workers to 15 by default: training runs are the real work here.
                os.environ.setdefault("RAY_worker_niceness", "0")
                _quiet_token_auth_notice()
                local = (max_parallel or max(1, (os.cpu_count() or 1) // cpus)) * cpus
                ray.init(address="local", num_cpus=local, **kwargs)  # never a stray cluster
        total = int(ray.cluster_resources().get("CPU", cpus))
        self.capacity = max_parallel or max(1, total // cpus)
        self._task = ray.remote(_ray_attempt)
        self._running: dict = {}  # ObjectRef -> Job

    def free_slots(self) -> int:
        return self.capacity - len(self._running)

    def submit(self, job: Job) -> None:
        ref = self._task.options(num_cpus=job.cpus, max_retries=0, name=job.name).remote(
            job.run_dir, job.options, job.cpus
        )
        self._running[ref] = job

    def wait(self, timeout: float) -> list[tuple[Job, Outcome]]:
        ray = self._ray
        refs = list(self._running)
        if not refs:
            return []
        ready, _ = ray.wait(refs, num_returns=len(refs), timeout=timeout)
        done = []
        for ref in ready:
            job = self._running.pop(ref)
            try:
                result = ray.get(ref)
            except Exception as exc:  # the worker died or the task raised outside train
                text = f"{type(exc).__name__}: {exc}"
                done.append((job, Outcome(False, text.splitlines()[0], traceback=text + "\n")))
                continue
            outcome = Outcome(bool(result["ok"]), result.get("error"))
            outcome.retry = result.get("retry", True)
            done.append((job, outcome))
        return done

    def shutdown(self, interrupt: bool) -> None:
        ray = self._ray
        if interrupt:
            for ref in self._running:
                ray.cancel(ref)  # a KeyboardInterrupt inside the task: train marks it
            if self._running:
                ray.wait(list(self._running), num_returns=len(self._running), timeout=30)
        self._running.clear()
        if self._owns:
            ray.shutdown()
