"""Replays the run-safety failure list as a careful user would and prints `ok` or `defect` per item.

Each item runs real `acl3d` commands (tiny PPO runs on Stump Tracks; item 8 a two-node Ray
cluster on this machine, scripts/ray_cluster_check.py) in a scratch folder and
checks what a user relies on: a refused command exits 2 with one line naming the option and
writes nothing; a run directory is used by one process at a time; a damaged checkpoint is
skipped for the previous one; no raw traceback for any mistake on the list. Item 11 damages
copies of a run as a crash or a hand edit would (a torn evals.csv, a stale LATEST, 'running'
left by a dead process, an edited rng.json, a truncated model.zip) and checks that analyze,
resume, campaign status and evaluate say so, carry on, and lose none of the run's other files.

    python scripts/probe_safety.py          # every item (a few minutes on 2 cores)
    python scripts/probe_safety.py 3 7      # some items

Add an item with `@item(N, "title")` on a function `(probe) -> list[Check]`. One file on
purpose (above the ~400-line guideline): each item is one user's story, read top to bottom, and
the file is a script people run, not a module others import.
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

    def reference(self) -> Path:
        """The finished 512-step run (checkpoints at 256 and 512), trained once; never modify."""
        if self._finished is None:
            self._finished = self.root / "finished"
            proc = self.acl3d("train", *TINY, *STEPS, "--out", self._finished)
            if proc.returncode != 0:
                raise RuntimeError(f"the reference run failed:\n{proc.stderr}")
        return self._finished

    def finished_run(self) -> Path:
        """A copy of the finished reference run."""
        copy = self.path("copy")
        shutil.copytree(self.reference(), copy)
        return copy

    def same_weights(self, a: Path, b: Path) -> subprocess.CompletedProcess:
        """Prints True when the final models of runs `a` and `b` hold the same weights."""
        return self.python(
            "import torch; from acl3d.training import students\n"
            f"a = students.load(None, {str(a / 'final_model.zip')!r}).policy.state_dict()\n"
            f"b = students.load(None, {str(b / 'final_model.zip')!r}).policy.state_dict()\n"
            "print(all(torch.equal(a[k], b[k]) for k in a))"
        )


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


def unchanged(before: dict, run: Path, name: str, may_change: tuple[str, ...] = ()) -> Check:
    """Every file as it was (none lost, none added), but those whose path starts with one of
    `may_change` (what the command is meant to write)."""
    after = snapshot(run)
    changed = sorted(
        k
        for k in set(before) | set(after)
        if before.get(k) != after.get(k) and not k.startswith(may_change)
    )
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


# ---------------------------------------------------------------------- campaigns and evaluation
CAMPAIGN_SETS = {
    "n_envs": 2,
    "nb_test_episodes": 4,
    "env_kwargs": {"max_episode_steps": 50},
    "student_params": {"n_steps": 128, "batch_size": 64},
    "checkpoint_every": 256,
    "eval_every": 1024,
    "verbose": 0,
}


def campaign_args(out: Path, steps: int, *extra: str, sets: dict | None = None) -> list[str]:
    args = ["campaign", "run", "quick", "--out", out, "--seeds", "1", *extra]
    for key, value in {**CAMPAIGN_SETS, "steps": steps, **(sets or {})}.items():
        args += ["--set", f"{key}={json.dumps(value)}"]
    return args


def attempt_lines(run: Path) -> list[str]:
    log = run / "campaign.log"
    lines = log.read_text().splitlines() if log.exists() else []
    return [line for line in lines if line.startswith("[campaign]") and " pid " in line]


def pid_alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@item(2, "a killed campaign leaves no attempt training; continuing it runs one attempt per run")
def campaign_children(probe: Probe) -> list[Check]:
    out = probe.path("campaign")
    args = campaign_args(out, 2048, "--executor", "local", "--max-parallel", "2")
    driver = subprocess.Popen(
        [sys.executable, "-m", "acl3d", *map(str, args)],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline = time.time() + 240
        while not list(out.glob("runs/*/checkpoints/LATEST")) and time.time() < deadline:
            time.sleep(0.2)
        os.kill(driver.pid, signal.SIGKILL)  # the campaign process only, as `kill -9 PID`
        driver.wait()
        resumable = {p.parts[-3] for p in out.glob("runs/*/checkpoints/LATEST")}
        orphans = [
            int(line.split(" pid ")[1].split(":")[0].split()[0])
            for run in out.glob("runs/*")
            for line in attempt_lines(run)
        ]
        again = probe.acl3d(*args, timeout=600)  # at once, while the attempts may still end
    finally:
        try:
            os.killpg(driver.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    checks = [
        Check("the same command continues it", again.returncode == 0, again.stderr[-160:]),
        Check(
            "the killed campaign's attempts ended", not any(map(pid_alive, orphans)), str(orphans)
        ),
    ]
    for run in sorted(out.glob("runs/*")):
        whats = [line.split(": ", 1)[1].split(";")[0] for line in attempt_lines(run)]
        then = "resuming" if run.name in resumable else "starting afresh"
        steps = [int(r.split(",")[0]) for r in (run / "episodes.csv").read_text().splitlines()[1:]]
        evals = [r.split(",")[0] for r in (run / "evals.csv").read_text().splitlines()[1:]]
        checks += [
            Check(f"{run.name}: finished", status(run) == "finished", str(status(run))),
            Check(
                f"{run.name}: one attempt per campaign process, the second {then}",
                len(whats) <= 2 and all(w.startswith(then) for w in whats[1:]),
                str(whats),
            ),
            Check(f"{run.name}: no failed attempt", not (run / "failures").exists()),
            Check(f"{run.name}: episodes in step order", steps == sorted(steps)),
            Check(f"{run.name}: each evaluation once", len(evals) == len(set(evals)), str(evals)),
        ]
    return checks


@item(6, "campaign spec values, the campaign lock, exclude, a failed start")
def campaign_checks(probe: Probe) -> list[Check]:
    checks = []
    for key, value in (("steps", -5), ("n_envs", 0), ("n_envs", 5000), ("teacher", "nope")):
        out = probe.path("badset")
        proc = probe.acl3d(*campaign_args(out, 512, sets={key: value}), timeout=60)
        checks.append(refused(proc, key, f"--set {key}={value}"))
        checks.append(Check(f"--set {key}={value} writes nothing", not out.exists()))
    for key, value in (("steps", -4096), ("eval_every", -3), ("reset_student_every", -7000)):
        spec = probe.path("spec.yaml")
        base = {**CAMPAIGN_SETS, "steps": 4096, "student": "ppo", "preset": "fast", key: value}
        spec.write_text(json.dumps({"name": "neg", "base": base, "grid": {"teacher": ["random"]}}))
        out = probe.path("negative")
        proc = probe.acl3d("campaign", "run", spec, "--out", out, "--budget", "0.5", timeout=60)
        checks.append(refused(proc, key, f"spec {key}: {value} (--budget 0.5)"))
        checks.append(Check(f"spec {key}: {value} writes nothing", not out.exists()))
    spec = probe.path("excluded.yaml")
    spec.write_text(
        json.dumps(
            {"name": "none", "grid": {"teacher": ["random"]}, "exclude": [{"teacher": "random"}]}
        )
    )
    proc = probe.acl3d("campaign", "run", spec, "--out", probe.path("none"), timeout=60)
    checks.append(refused(proc, "remove every run", "an exclude removing every run says so"))

    out = probe.path("locked")
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time\n"
            "from acl3d.campaign import CampaignDir, load_spec\n"
            f"spec = load_spec('quick').scaled(seeds=2)\n"
            f"camp = CampaignDir({str(out)!r})\n"
            "with camp.lock():\n"
            "    camp.prepare(spec, spec.expand(), {})\n"
            "    print('held', flush=True)\n"
            "    time.sleep(120)\n",
        ],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        holder.stdout.readline()
        before = (out / "campaign.yaml").read_bytes()
        proc = probe.acl3d("campaign", "run", "quick", "--out", out, "--seeds", "3", timeout=60)
        checks.append(refused(proc, "in use", "a second campaign process is refused"))
        after = (out / "campaign.yaml").read_bytes()
        checks.append(Check("... and campaign.yaml is unchanged", after == before))
    finally:
        holder.kill()
        holder.wait()
    proc = probe.python(
        "import multiprocessing as mp, time\n"
        "from acl3d.campaign import CampaignDir\n"
        "from acl3d.campaign.lock import LockBusy\n"
        "def take(path, start, got):\n"
        "    start.wait()\n"
        "    try:\n"
        "        with CampaignDir(path).lock():\n"
        "            got.put(1); time.sleep(1.0)\n"
        "    except LockBusy:\n"
        "        got.put(0)\n"
        "if __name__ == '__main__':\n"
        "    ctx = mp.get_context('fork'); start = ctx.Barrier(8); got = ctx.Queue()\n"
        f"    procs = [ctx.Process(target=take, args=({str(probe.path('race'))!r}, start, got))"
        " for _ in range(8)]\n"
        "    [p.start() for p in procs]; [p.join() for p in procs]\n"
        "    print(sum(got.get() for _ in procs))\n"
    )
    holders = proc.stdout.strip()
    checks.append(Check("8 simultaneous campaign locks: one holder", holders == "1", holders))

    out = probe.path("failedstart")
    wrong = campaign_args(out, 128, "--executor", "local", sets={"teacher_params": {"nope": 1}})
    first = probe.acl3d(*wrong, timeout=300)
    right = probe.acl3d(*campaign_args(out, 128, "--executor", "local"), timeout=300)
    checks.append(Check("a failed start ...", first.returncode == 1, first.stderr[-160:]))
    checks.append(
        Check(
            "... does not block the corrected command", right.returncode == 0, right.stderr[-160:]
        )
    )
    return checks


@item(8, "a campaign on a real two-node Ray cluster, a node and the campaign killed mid-run")
def ray_cluster(probe: Probe) -> list[Check]:
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "ray_cluster_check.py")],
        capture_output=True,
        text=True,
        timeout=900,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    checks = [
        Check(line[7:], line.startswith("ok"))
        for line in proc.stdout.splitlines()
        if line.startswith(("ok     ", "FAILED "))
    ]
    return checks or [Check("scripts/ray_cluster_check.py ran", False, proc.stderr[-160:])]


@item(9, "stochastic evaluation does not change the training run")
def evaluation_streams(probe: Probe) -> list[Check]:
    runs = []
    for every in (256, 512):
        out = probe.path(f"eval_every_{every}")
        proc = probe.acl3d(
            "train", *TINY, "--steps", "1024", "--eval-stochastic", "--eval-every", every,
            "--out", out, timeout=300,
        )  # fmt: skip
        if proc.returncode != 0:
            return [Check(f"--eval-every {every} trains", False, proc.stderr[-160:])]
        runs.append(out)
    a, b = runs
    same = (a / "episodes.csv").read_text() == (b / "episodes.csv").read_text()
    weights = probe.same_weights(a, b)
    return [
        Check("--eval-every 256 vs 512: episodes.csv identical row for row", same),
        Check(
            "... and the same final weights",
            weights.stdout.strip() == "True",
            weights.stderr[-160:],
        ),
    ]


@item(10, "input checks: bounds, torn configs, resource bounds, names, files, usage")
def input_checks(probe: Probe) -> list[Check]:
    checks = []
    run = probe.finished_run()
    before = snapshot(run)
    args = ("--bounds", "stump_height=0,100", "--out", run, "--overwrite")
    proc = probe.acl3d("train", *TINY, *STEPS, *args, timeout=60)
    checks += [refused(proc, "--bounds", "--bounds beyond the buildable range, --overwrite")]
    checks.append(unchanged(before, run, "... the run --overwrite would replace is kept"))
    run = probe.finished_run()
    (run / "config.yaml").write_bytes((run / "config.yaml").read_bytes()[:395])
    proc = probe.acl3d("evaluate", run, timeout=60)
    checks.append(refused(proc, "config.yaml", "evaluate on a torn config.yaml"))

    big, bad = probe.path("big.json"), probe.path("bad.json")
    big.write_text(json.dumps([{"stump_height": 1.0}] * 150_000))
    bad.write_text('[{"stump_height": 1.0,\n')
    net = "policy_kwargs={net_arch: [65536, 65536, 65536]}"
    for name, option, extra in (
        ("a test set of 150,000 tasks", "--test-set", ("--test-set", big)),
        ("a test set with a JSON syntax error", "--test-set", ("--test-set", bad)),
        ("net_arch [65536] x 3", "net_arch", ("--student-param", net)),
        ("a 300-character --out", "--out", ("--out", probe.root / ("x" * 300))),
        ("a teacher misspelt alp_gmm", "did you mean 'alp-gmm'", ("--teacher", "alp_gmm")),
    ):
        out = probe.path("input")
        proc = probe.acl3d("train", *TINY, *STEPS, "--out", out, *extra, timeout=120)
        checks.append(refused(proc, option, name))
        checks.append(Check(f"{name} writes nothing", not out.exists()))
    config = probe.path("list.yaml")
    config.write_text("env_kwargs: [1, 2]\n")
    proc = probe.acl3d("train", "--config", config, "--env-kwarg", "max_episode_steps=50")
    checks.append(refused(proc, "env_kwargs", "a config file's env_kwargs: [1, 2]"))
    proc = probe.acl3d("train", "--task", "stump_height=1", timeout=60)
    checks.append(refused(proc, "--task", "train --task: train's usage"))
    checks.append(Check("... train's usage", proc.stderr.startswith("usage: acl3d train")))

    run = probe.finished_run()
    for name, option, args in (
        ("evaluate --episodes 100000", "--episodes", ("evaluate", run, "--episodes", "100000")),
        ("render --episodes 1e9", "--episodes", ("render", "--episodes", "1000000000")),
        ("analyze --reps 1e12", "reps", ("analyze", probe.root, "--reps", str(10**12))),
    ):
        checks.append(refused(probe.acl3d(*args, timeout=120), option, name))
    run = probe.finished_run()
    truncate(run / "teacher.npz")
    proc = probe.acl3d("render", "--curriculum", run, "--out", probe.path("c.gif"), timeout=60)
    checks.append(no_traceback(proc, "render --curriculum on a truncated teacher.npz", says="npz"))

    for key, value in (
        ("env_kwargs", {"bogus": 1}),
        ("test_set", "missing.json"),
        ("bounds", {"stump_height": [3, 1]}),
    ):
        out = probe.path("camp")
        proc = probe.acl3d(*campaign_args(out, 512, "--executor", "local", sets={key: value}))
        checks.append(refused(proc, key if key != "bounds" else "min <= max", f"campaign {key}"))
        checks.append(Check(f"campaign {key}: nothing written", not out.exists()))
    for name, doc, extra, says in (
        ("exclude: 5", {"exclude": 5}, (), "exclude"),
        ("--budget 1e306", {"base": {"steps": 4096}}, ("--budget", "1e306"), "budget"),
        (
            "a 300-byte run name",
            {"base": {"steps": 64}, "grid": {"c": {"a" * 300: {}}}},
            (),
            "run name",
        ),
    ):
        spec = probe.path("spec.yaml")
        spec.write_text(json.dumps({"name": "x", "grid": {"teacher": ["random"]}, **doc}))
        out = probe.path("camp")
        proc = probe.acl3d("campaign", "run", spec, "--out", out, *extra, timeout=60)
        checks.append(refused(proc, says, f"campaign spec {name}"))
        checks.append(Check(f"campaign spec {name}: nothing written", not out.exists()))

    shipped = ROOT / "acl3d" / "results" / "stump-v1"
    proc = subprocess.run(
        [sys.executable, "-m", "acl3d", "analyze", str(shipped), "--reps", "200"],
        capture_output=True, text=True, timeout=300, cwd=probe.root,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    checks.append(
        Check(
            "analyze of the shipped results writes under the current directory",
            proc.returncode == 0
            and (probe.root / "report_stump-v1" / "report.md").exists()
            and not (shipped / "report").exists(),
            proc.stderr[-160:],
        )
    )
    proc = probe.python(
        "import gymnasium as gym, acl3d\n"
        "gym.make_vec('acl3d/StumpTracks-v0', 2, vectorization_mode='sync', teacher=object())"
    )
    checks.append(
        Check(
            "make_vec sync with a teacher points to vector_entry_point",
            'vectorization_mode="vector_entry_point"' in proc.stderr,
            proc.stderr.strip()[-160:],
        )
    )
    return checks


# ---------------------------------------------------------------------- run-directory faults
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
