"""What every item of `scripts/probe_safety.py` uses: the scratch folder and the `acl3d`
command (`Probe`), the item registry, and the checks of what a user relies on."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
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
