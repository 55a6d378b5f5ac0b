"""Items on campaigns: a killed campaign's children, spec values and the campaign lock, a
real two-node Ray cluster."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from safety_probe.kit import CAMPAIGN_SETS, ROOT, Check, Probe, campaign_args, item, refused, status


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
