"""Replays the run-safety failure list as a careful user would and prints `ok` or `defect` per item.

Each item runs real `acl3d` commands (tiny PPO runs on Stump Tracks) in a scratch folder and
checks what a user relies on: a refused command exits 2 with one line naming the option and
writes nothing; a run directory is used by one process at a time; a damaged checkpoint is
skipped for the previous one; no raw traceback for any mistake on the list.

    python scripts/probe_safety.py          # every item (a few minutes on 2 cores)
    python scripts/probe_safety.py 3 7      # some items

Add an item with `@item(N, "title")` on a function `(probe) -> list[Check]`.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TINY = [
    "--teacher", "random", "--student", "ppo", "--preset", "fast", "--n-envs", "2",
    "--nb-test-episodes", "4", "--env-kwarg", "max_episode_steps=50",
    "--student-param", "n_steps=128", "--student-param", "batch_size=64",
    "--eval-every", "256", "--checkpoint-every", "256", "--no-progress", "--quiet",
]  # fmt: skip
STEPS = ["--steps", "512"]


@dataclass
class Check:
    name: str
    ok: bool
    detail: str = ""


ITEMS: dict[int, tuple[str, Callable]] = {}


def item(number: int, title: str):
    def register(fn):
        ITEMS[number] = (title, fn)
        return fn

    return register


class Probe:
    """A scratch folder, the `acl3d` command and a finished tiny run to copy."""

    def __init__(self, root: Path):
        self.root = root
        self._finished: Path | None = None
        self._n = 0

    def path(self, name: str) -> Path:
        self._n += 1
        return self.root / f"{self._n:03d}_{name}"

    def acl3d(self, *args, timeout: float = 300, env: dict | None = None):
        return subprocess.run(
            [sys.executable, "-m", "acl3d", *map(str, args)],
            capture_output=True,
            text=True,
            timeout=timeout,
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": str(ROOT), **(env or {})},
        )

    def python(self, code: str, timeout: float = 300):
        return subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            timeout=timeout,
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
        )

    def finished_run(self) -> Path:
        """A copy of a finished 512-step run (checkpoints at 256 and 512)."""
        if self._finished is None:
            self._finished = self.root / "finished"
            proc = self.acl3d("train", *TINY, *STEPS, "--out", self._finished)
            if proc.returncode != 0:
                raise RuntimeError(f"the reference run failed:\n{proc.stderr}")
        copy = self.path("copy")
        shutil.copytree(self._finished, copy)
        return copy


# ---------------------------------------------------------------------- what a user relies on
def refused(proc, option: str, name: str) -> Check:
    """Exit 2 with one line that names `option` (after argparse's usage, for its own checks),
    no traceback."""
    lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
    usage = lines[0].startswith("usage:") and all(line[0].isspace() for line in lines[1:-1])
    ok = proc.returncode == 2 and (len(lines) == 1 or usage) and option in lines[-1]
    shown = lines[-1] if lines else ""
    return Check(name, ok, f"exit {proc.returncode}, {len(lines)} line(s): {shown[:160]}")


def no_traceback(proc, name: str, want_rc: int = 2, says: str = "") -> Check:
    lines = proc.stderr.strip().splitlines()
    ok = proc.returncode == want_rc and "Traceback" not in proc.stderr and says in proc.stderr
    shown = lines[-1] if lines else ""
    return Check(name, ok, f"exit {proc.returncode}: {shown[:160]}")


def snapshot(run: Path) -> dict[str, bytes]:
    return {str(p.relative_to(run)): p.read_bytes() for p in sorted(run.rglob("*")) if p.is_file()}


def unchanged(before: dict, run: Path, name: str) -> Check:
    after = snapshot(run)
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    return Check(name, not changed, f"changed: {changed[:5]}" if changed else "")


def status(run: Path) -> str | None:
    path = run / "status.json"
    return json.loads(path.read_text())["status"] if path.exists() else None


def latest(run: Path) -> Path:
    return run / "checkpoints" / (run / "checkpoints" / "LATEST").read_text().strip()


def truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def edit_config(run: Path, **values) -> None:
    import yaml

    doc = yaml.safe_load((run / "config.yaml").read_text())
    doc["config"].update(values)
    (run / "config.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))


# ---------------------------------------------------------------------- the items
@item(1, "bounds that protect the machine (memory, threads)")
def bounds(probe: Probe) -> list[Check]:
    checks = []
    for option, value in (("--nb-test-episodes", "1000000000"), ("--torch-threads", "100000")):
        out = probe.path("bounds")
        proc = probe.acl3d("train", *TINY, *STEPS, option, value, "--out", out, timeout=60)
        checks.append(refused(proc, option, f"{option} {value}"))
        checks.append(Check(f"{option} {value} writes nothing", not out.exists()))
    return checks


@item(3, "a run directory is locked: --resume R while R trains is refused")
def lock(probe: Probe) -> list[Check]:
    out = probe.path("locked")
    first = subprocess.Popen(
        [sys.executable, "-m", "acl3d", "train", *TINY, "--steps", "100000", "--out", str(out)],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.time() + 240
        while not (out / "checkpoints" / "LATEST").exists() and time.time() < deadline:
            time.sleep(0.5)
        before = (out / "status.json").read_text()
        second = probe.acl3d("train", "--resume", out, "--steps", "200000", timeout=120)
        checks = [
            refused(second, "in use", "a second process is refused"),
            Check(
                "the running run's status is untouched", (out / "status.json").read_text() == before
            ),
        ]
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait()
    again = probe.acl3d("train", "--resume", out, "--steps", "1024", timeout=300)
    checks.append(Check("a killed run's lock is released: it resumes", again.returncode == 0,
                        again.stderr.strip()[-160:]))  # fmt: skip
    rows = [r.split(",")[0] for r in (out / "evals.csv").read_text().splitlines()[1:]]
    checks.append(
        Check("evals.csv has each evaluation once", len(rows) == len(set(rows)), str(rows))
    )
    return checks


@item(4, "options checked before anything is written; resume verifies its checkpoint")
def before_writing(probe: Probe) -> list[Check]:
    checks = []
    for option, value in (
        ("--n-envs", "4097"),
        ("--eval-envs", "100000"),
        ("--seed", "4294967296"),
        ("--student-param", "learning_rate=-1"),
        ("--env-kwarg", "max_episode_steps=-1"),
        ("--device", "bogus"),
        ("--torch-threads", "100000"),
    ):
        out = probe.path("option")
        proc = probe.acl3d("train", *TINY, *STEPS, option, value, "--out", out, timeout=60)
        checks.append(refused(proc, option, f"{option} {value}"))
        checks.append(Check(f"{option} {value} writes nothing", not out.exists()))
    for damaged in (
        "model.zip",
        "controller.npz",
        "runtime.npz",
        "rng.npz",
        "model_vecnormalize.npz",
    ):
        run = probe.finished_run()
        truncate(latest(run) / damaged)
        proc = probe.acl3d("train", "--resume", run, "--steps", "768", timeout=300)
        checks.append(
            Check(
                f"a truncated {damaged} falls back to the previous checkpoint",
                proc.returncode == 0 and "skipping damaged checkpoint" in proc.stderr,
                proc.stderr.strip()[-160:],
            )
        )
    run = probe.finished_run()
    for folder in (run / "checkpoints").glob("step_*"):
        truncate(folder / "model.zip")
    before = snapshot(run)
    proc = probe.acl3d("train", "--resume", run, "--steps", "768", timeout=120)
    checks.append(no_traceback(proc, "every checkpoint damaged: refused", says="damaged"))
    checks.append(unchanged(before, run, "every checkpoint damaged: config and status kept"))
    for field, value in (("teacher", "alp-gmm"), ("n_envs", 4), ("student", "sac"), ("seed", 5)):
        run = probe.finished_run()
        edit_config(run, **{field: value})
        before = snapshot(run)
        proc = probe.acl3d("train", "--resume", run, "--steps", "768", timeout=120)
        checks.append(refused(proc, field, f"an edited {field} in config.yaml"))
        checks.append(unchanged(before, run, f"an edited {field}: nothing rewritten"))
    return checks


@item(5, "test-set tasks are checked at start")
def test_set(probe: Probe) -> list[Check]:
    checks = []
    for height in (100, 1e308):
        tasks = probe.path("tasks.json")
        tasks.write_text(json.dumps([{"stump_height": height, "obstacle_spacing": 2.0}]))
        out = probe.path("testset")
        proc = probe.acl3d("train", *TINY, *STEPS, "--test-set", tasks, "--out", out, timeout=60)
        checks.append(refused(proc, "test set", f"stump_height {height}"))
        checks.append(Check(f"stump_height {height} writes nothing", not out.exists()))
    return checks


@item(7, "dead ends and tracebacks")
def tracebacks(probe: Probe) -> list[Check]:
    checks = []
    out = probe.path("inf")
    proc = probe.acl3d("train", *TINY, "--steps", "inf", "--out", out, timeout=60)
    checks.append(refused(proc, "--steps", "--steps inf"))

    bad_yaml = probe.path("bad.yaml")
    bad_yaml.write_text("teacher: [random\nsteps: 1\n")
    proc = probe.acl3d("train", "--config", bad_yaml, "--out", probe.path("yaml"), timeout=60)
    checks.append(refused(proc, "--config", "malformed --config YAML"))

    run = probe.finished_run()
    doc = (run / "config.yaml").read_text()
    import yaml

    parsed = yaml.safe_load(doc)
    parsed.pop("resolved")
    (run / "config.yaml").write_text(yaml.safe_dump(parsed, sort_keys=False))
    proc = probe.acl3d("train", "--resume", run, "--steps", "768", timeout=60)
    checks.append(no_traceback(proc, "config.yaml missing 'resolved'", says="resolved"))

    out = probe.path("bogus")
    proc = probe.acl3d("train", *TINY, *STEPS, "--env-kwarg", "bogus=1", "--out", out, timeout=60)
    checks.append(refused(proc, "--env-kwarg", "--env-kwarg bogus=1"))

    a_file = probe.path("a_file")
    a_file.write_text("x")
    for out in (a_file, a_file / "run"):
        proc = probe.acl3d("train", *TINY, *STEPS, "--out", out, timeout=60)
        checks.append(
            refused(proc, "out", f"--out {out.relative_to(probe.root)} (at/under a file)")
        )

    if os.geteuid() != 0:  # root writes through permissions: tests/ inject EROFS instead
        read_only = probe.path("read_only")
        read_only.mkdir(mode=0o555)
        proc = probe.acl3d("train", *TINY, *STEPS, "--out", read_only / "run", timeout=60)
        checks.append(refused(proc, "out", "--out in a read-only folder"))

    run = probe.finished_run()
    truncate(run / "teacher.npz")
    proc = probe.acl3d("evaluate", run, "--out", probe.path("e.csv"), timeout=120)
    checks.append(no_traceback(proc, "a truncated teacher.npz is named", says="teacher"))

    run = probe.finished_run()
    missing = probe.path("missing") / "evals.csv"
    proc = probe.acl3d("evaluate", run, "--out", missing, timeout=60)
    checks.append(refused(proc, "--out", "evaluate --out into a missing folder"))
    checks.append(Check("... refused before evaluating", "evaluating" not in proc.stdout))

    run = probe.finished_run()
    truncate(run / "teacher.json")
    report = probe.path("report")
    proc = probe.acl3d("report", run, "--no-video", "--out", report, timeout=60)
    checks.append(no_traceback(proc, "report on a truncated teacher.json", says="teacher"))
    checks.append(Check("... writes no PNG", not report.exists()))

    out = probe.path("nocheckpoint")
    proc = probe.python(
        "import sys; from acl3d.cli import main; from acl3d.training import session\n"
        "def stop(*a): raise KeyboardInterrupt\n"
        "session.Session.save_checkpoint = stop\n"
        f"sys.exit(main(['train', *{TINY!r}, *{STEPS!r}, '--out', {str(out)!r}]))"
    )
    proc = probe.acl3d("train", "--resume", out, "--steps", "512", timeout=60)
    checks.append(no_traceback(proc, "no checkpoint: resume says how", says="--overwrite"))
    proc = probe.acl3d("train", *TINY, *STEPS, "--out", out, timeout=60)
    checks.append(no_traceback(proc, "no checkpoint: a new run says how", says="--overwrite"))
    proc = probe.acl3d("train", *TINY, *STEPS, "--out", out, "--overwrite", timeout=300)
    checks.append(Check("--overwrite starts it again", proc.returncode == 0, proc.stderr[-160:]))

    out = probe.path("full")
    proc = probe.python(
        "import errno, os, sys; from acl3d.cli import main; from acl3d.training import session\n"
        "calls = []\n"
        "write = session.Session._write_checkpoint\n"
        "def full(self, folder):\n"
        "    calls.append(folder)\n"
        "    if len(calls) == 2: raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(folder))\n"
        "    write(self, folder)\n"
        "session.Session._write_checkpoint = full\n"
        f"sys.exit(main(['train', *{TINY!r}, *{STEPS!r}, '--out', {str(out)!r}]))"
    )
    lines = proc.stderr.strip().splitlines()
    checks.append(
        Check(
            "a full disk: one line saying so",
            proc.returncode == 1 and len(lines) == 1 and "no space left" in lines[0],
            lines[-1][:160] if lines else "",
        )
    )
    checks.append(
        Check("... status is not left running", status(out) == "crashed", str(status(out)))
    )
    temps = [p.name for p in out.rglob("*") if p.name.endswith(".tmp") or "_tmp" in p.name]
    checks.append(Check("... no temporary file left", not temps, str(temps)))
    proc = probe.acl3d("train", "--resume", out, timeout=300)
    checks.append(Check("... and the run resumes", proc.returncode == 0, proc.stderr[-160:]))

    run = probe.finished_run()
    for name in (f"_teacher_{12345}_tmp.json", f"_teacher_{12345}_tmp.npz", ".status.json.1.tmp"):
        (run / name).write_text("left by a killed writer")
    proc = probe.acl3d("train", "--resume", run, "--steps", "768", timeout=300)
    temps = [p.name for p in run.iterdir() if p.name.endswith(".tmp") or "_tmp." in p.name]
    checks.append(Check("temporary files of a killed writer are removed", not temps, str(temps)))
    return checks


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("items", nargs="*", type=int, help="item numbers (default: all)")
    parser.add_argument("--keep", action="store_true", help="keep the scratch folder")
    args = parser.parse_args()
    numbers = args.items or sorted(ITEMS)
    root = Path(tempfile.mkdtemp(prefix="acl3d_probe_"))
    defects = 0
    try:
        probe = Probe(root)
        for number in numbers:
            title, run = ITEMS[number]
            started = time.perf_counter()
            try:
                checks = run(probe)
            except Exception as exc:  # a probe that cannot run is a defect too
                checks = [Check("the probe ran", False, f"{type(exc).__name__}: {exc}")]
            bad = [c for c in checks if not c.ok]
            defects += bool(bad)
            took = time.perf_counter() - started
            print(f"item {number}: {'defect' if bad else 'ok'} ({title}; {took:.0f} s)")
            for c in checks:
                print(
                    f"    {'ok    ' if c.ok else 'DEFECT'} {c.name}"
                    + (f": {c.detail}" if c.detail and not c.ok else "")
                )
    finally:
        if args.keep:
            print(f"scratch folder kept: {root}")
        else:
            shutil.rmtree(root, ignore_errors=True)
    return 1 if defects else 0


if __name__ == "__main__":
    sys.exit(main())
