"""Items on single training runs: resource bounds, the run lock, checks before writing,
test sets, tracebacks, evaluation streams and input checks."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

from safety_probe.kit import (
    ROOT,
    STEPS,
    TINY,
    Check,
    Probe,
    campaign_args,
    edit_config,
    item,
    latest,
    no_traceback,
    refused,
    snapshot,
    status,
    truncate,
    unchanged,
)


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
