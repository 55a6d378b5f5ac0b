"""A campaign on a real Ray cluster, with a node and then the campaign process killed mid-run.

The cluster is run the way a real one is (docs/scaling-out.md), here on one machine: a head
(`ray start --head`) and a second node (`ray start --address HEAD`), separate processes with
their own CPU, sharing the output directory. Steps, each checked:

1. a reference: the same campaign with the local executor;
2. the campaign submitted to the cluster with `--address`; its runs go to both nodes;
3. the second node is SIGKILLed (raylet and workers) once a run on it has a checkpoint: its
   attempt fails, is retried on the head and resumes from that checkpoint;
4. the campaign process is SIGKILLed: its running attempt is ended by Ray (no orphan trains);
5. the same command continues the campaign to its end.

Every run must end finished exactly once (one start, resumes only after a kill), with the same
episodes, evaluations and final weights as the reference. Prints ok/FAILED per check; exit 1 on
any failure. About two minutes on 2 cores.

    python scripts/ray_cluster_check.py [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Tiny real runs: 2048 steps of PPO in 256-step rollouts, 40-step episodes, a 4-task test set.
SETS = {
    "steps": 2048,
    "n_envs": 1,
    "vec_env": "dummy",
    "nb_test_episodes": 4,
    "env_kwargs": {"max_episode_steps": 40},
    "student_params": {"n_steps": 256, "batch_size": 64, "n_epochs": 1},
    "checkpoint_every": 256,
    "eval_every": 512,
    "verbose": 0,
}
SEEDS = 2  # the quick spec: random and alp-gmm x 2 seeds = 4 runs
TIMEOUT_S = 600.0


class Checks:
    def __init__(self):
        self.failed = 0

    def __call__(self, ok: bool, what: str) -> bool:
        print(f"{'ok    ' if ok else 'FAILED'} {what}", flush=True)
        self.failed += not ok
        return ok


def campaign_cmd(out: Path, *extra: str, seeds: int = SEEDS, sets: dict = SETS) -> list[str]:
    """`acl3d campaign run quick` into `out`, 2 runs at a time."""
    cmd = [sys.executable, "-m", "acl3d", "campaign", "run", "quick", "--out", str(out)]
    cmd += ["--seeds", str(seeds), "--max-parallel", "2", *extra]
    for key, value in sets.items():
        cmd += ["--set", f"{key}={json.dumps(value)}"]
    return cmd


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def parent(pid: int) -> int | None:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[1].split()
    return None if fields[0] == "Z" else int(fields[1])


def alive(pid: int) -> bool:
    return parent(pid) is not None


class Node:
    """One Ray node: `ray start --block` in its own process group, declaring one CPU and a
    resource named after the node."""

    def __init__(self, name: str, args: list[str], env: dict, logs: Path):
        self.name = name
        ray = str(Path(sys.executable).with_name("ray"))
        self.log = (logs / f"ray_{name}.log").open("w")
        cmd = [ray, "start", "--block", "--num-cpus", "1", "--disable-usage-stats", *args]
        cmd += ["--node-ip-address", "127.0.0.1", "--resources", json.dumps({name: 1})]
        self.proc = subprocess.Popen(
            cmd, env=env, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True
        )

    def kill(self) -> None:
        """SIGKILL the node: its raylet, and with it the node's workers."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait()
        self.log.close()


@dataclass
class Cluster:
    address: str
    nodes: dict[str, Node]
    names: dict[str, str]  # Ray node id -> node name
    env: dict[str, str]  # for every client: this checkout's acl3d, the cluster's token


@contextmanager
def cluster(work: Path) -> Iterator[Cluster]:
    """A head and a second node on this machine. Its clients are subprocesses given `env`: a
    process that joined a Ray cluster keeps its token, and could not start another Ray later."""
    path = os.environ.get("PYTHONPATH", "")
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), path])),
        "RAY_AUTH_MODE": "token",  # one token shared by every process of the cluster
        "RAY_AUTH_TOKEN": secrets.token_hex(32),
    }
    address = f"127.0.0.1:{free_port()}"
    nodes: dict[str, Node] = {}
    try:
        head = ["--head", "--port", address.rsplit(":", 1)[1], "--include-dashboard", "false"]
        nodes["head"] = Node("head", head, env, work)
        nodes["worker"] = Node("worker", ["--address", address], env, work)
        yield Cluster(address, nodes, node_names(address, len(nodes), env), env)
    finally:
        for node in reversed(nodes.values()):
            node.kill()


def wait_for(what: str, condition, timeout: float = TIMEOUT_S, poll: float = 0.1):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(poll)
    raise TimeoutError(f"timed out waiting for {what}")


def attempts(run: Path) -> list[tuple[int, str, str]]:
    """(pid, Ray node id, what) of each attempt the run's campaign log records."""
    try:
        text = (run / "campaign.log").read_text()
    except OSError:
        return []
    out = []
    for line in text.splitlines():
        if line.startswith("[campaign]") and " ray node " in line and "; acl3d imported" in line:
            who, what = line.split(" pid ", 1)[1].split(": ", 1)
            pid, node = who.split(" ray node ")
            out.append((int(pid), node, what.split(";")[0]))
    return out


def node_names(address: str, count: int, env: dict[str, str]) -> dict[str, str]:
    """Ray node id -> the name of the resource the node declares, once `count` nodes are up."""
    code = (
        "import json, sys, time, ray\n"
        f"ray.init(address={address!r}, logging_level='ERROR', log_to_driver=False)\n"
        f"while len(alive := [n for n in ray.nodes() if n['Alive']]) < {count}:\n"
        "    time.sleep(0.2)\n"
        "print(json.dumps({n['NodeID']: sorted(set(n['Resources']) & {'head', 'worker'})[0]"
        " for n in alive}))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=TIMEOUT_S
    )
    if proc.returncode != 0:
        raise RuntimeError(f"the cluster did not come up:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def running(run: Path) -> bool:
    try:
        return json.loads((run / "status.json").read_text())["status"] == "running"
    except (OSError, ValueError, KeyError):
        return False


def checkpoint(run: Path) -> str | None:
    try:
        return (run / "checkpoints" / "LATEST").read_text().strip()
    except OSError:
        return None


def placement(runs: Path, names: dict[str, str]) -> list[tuple[str, int, int, str]]:
    """(run, attempt, pid, node name) of every attempt so far."""
    return [
        (run.name, i, pid, names.get(node, node))
        for run in sorted(runs.iterdir() if runs.exists() else ())
        for i, (pid, node, _) in enumerate(attempts(run))
    ]


def same_run(a: Path, b: Path) -> str | None:
    """None when runs a and b trained the same (episodes, evaluations, final weights)."""
    import torch

    from acl3d.training import students

    for name in ("episodes.csv", "evals_tasks.csv"):
        if (a / name).read_text() != (b / name).read_text():
            return f"{name} differs"
    evals = [
        [r.rsplit(",", 1)[0] for r in (p / "evals.csv").read_text().splitlines()] for p in (a, b)
    ]
    if evals[0] != evals[1]:
        return "evals.csv differs"
    wa = students.load(None, a / "final_model.zip").policy.state_dict()
    wb = students.load(None, b / "final_model.zip").policy.state_dict()
    if any(not torch.equal(wa[k], wb[k]) for k in wa):
        return "final weights differ"
    return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--keep", help="work in this directory and keep it (default: a temp dir)")
    args = parser.parse_args()
    work = Path(args.keep or tempfile.mkdtemp(prefix="acl3d_ray_cluster_"))
    work.mkdir(parents=True, exist_ok=True)
    check = Checks()
    started = time.monotonic()
    reference, out = work / "local", work / "cluster"
    runs = out / "runs"
    try:
        with cluster(work) as c:
            print(f"[1] reference campaign, local executor -> {reference}", flush=True)
            local = campaign_cmd(reference, "--executor", "local")
            subprocess.run(local, env=c.env, check=True, stdout=subprocess.DEVNULL)
            print(f"[2] cluster: head and a second node at {c.address}; campaign -> {out}")
            submit = campaign_cmd(out, "--address", c.address)
            driver = subprocess.Popen(submit, env=c.env, stdout=subprocess.DEVNULL)

            def running_on(node: str):
                """(run, pid) of a run whose latest attempt trains on `node` past a checkpoint."""
                for run, i, pid, where in placement(runs, c.names):
                    last = i == len(attempts(runs / run)) - 1
                    if last and where == node and running(runs / run) and checkpoint(runs / run):
                        return run, pid
                return None

            victim, pid = wait_for(
                "a run on the second node", lambda: running_on("worker"), poll=0.02
            )
            where = sorted({(run, node) for run, _, _, node in placement(runs, c.names)})
            check({n for _, n in where} == {"head", "worker"}, f"runs on both nodes: {where}")
            print(f"[3] SIGKILL the second node while {victim} trains on it (pid {pid})")
            c.nodes["worker"].kill()
            wait_for("the attempt on the killed node to end", lambda: not alive(pid), 60)
            latest = checkpoint(runs / victim)

            def resumed():
                found = running_on("head")
                return (
                    found
                    if found and found[0] == victim and checkpoint(runs / victim) != latest
                    else None
                )

            _, pid = wait_for(f"{victim} to resume on the head", resumed, poll=0.02)
            check(True, f"{victim} resumed on the head from {latest}, checkpointed since")
            print(f"[4] SIGKILL the campaign process while {victim} trains (pid {pid})")
            driver.send_signal(signal.SIGKILL)
            driver.wait()
            t0 = time.monotonic()
            try:
                wait_for("Ray to end the dead campaign's attempt", lambda: not alive(pid), 60)
                check(True, f"its attempt ended {time.monotonic() - t0:.1f} s after it")
            except TimeoutError:
                check(False, "its attempt still runs 60 s after it")

            print("[5] the same command continues the campaign", flush=True)
            rc = subprocess.run(submit, env=c.env, stdout=subprocess.DEVNULL).returncode
            check(rc == 0, f"continued campaign exit status {rc}")
        for run in sorted(p.name for p in (reference / "runs").iterdir()):
            status = json.loads((runs / run / "status.json").read_text())["status"]
            whats = [what for _, _, what in attempts(runs / run)]
            starts = sum(w == "starting afresh" for w in whats)
            diff = same_run(reference / "runs" / run, runs / run)
            check(
                status == "finished" and starts == 1 and diff is None,
                f"{run}: {status}, attempts {whats}, {diff or 'same as the local campaign'}",
            )
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    print(f"{'all ok' if not check.failed else f'{check.failed} FAILED'} "
          f"({time.monotonic() - started:.0f} s)")  # fmt: skip
    return 1 if check.failed else 0


if __name__ == "__main__":
    sys.exit(main())
