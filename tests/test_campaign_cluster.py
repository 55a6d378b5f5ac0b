"""A campaign submitted with `--address` to a real Ray cluster: a head and a second node started
as separate `ray start` processes with their own CPU; the runs go to both nodes.

A second node killed mid-run has its run retried on the head, resuming from its checkpoint. A
killed campaign process, and results equal to a local campaign's, take minutes to show on real
runs: scripts/ray_cluster_check.py checks them."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from ray_cluster_check import (  # noqa: E402
    SETS,
    attempts,
    campaign_cmd,
    checkpoint,
    cluster,
    placement,
    running,
    wait_for,
)

# sixteen 256-step rollouts per run, a checkpoint after each: long enough that the victim's
# attempt cannot finish in the seconds its node's processes take to die after the kill
STEPS = 4096


def early(run: Path) -> bool:
    """The run has a checkpoint and most of its rollouts still to train: a kill now lands
    mid-run (near its end the run may finish before its node's processes die)."""
    name = checkpoint(run)
    return bool(name) and int(name.rsplit("_", 1)[-1]) <= STEPS // 4


def test_campaign_runs_on_both_nodes_and_survives_a_node_killed_mid_run(tmp_path):
    """The runs start on both nodes; the second node is then SIGKILLed while its run trains past
    a checkpoint: that attempt fails, is retried on the head and resumes from the checkpoint, and
    the campaign ends with every run finished, each started once."""
    out, runs = tmp_path / "camp", tmp_path / "camp" / "runs"
    with cluster(tmp_path) as c:
        submit = campaign_cmd(out, "--address", c.address, seeds=1, sets={**SETS, "steps": STEPS})
        driver = subprocess.Popen(
            submit, env=c.env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        try:

            def on_worker():
                for run, _, _, node in placement(runs, c.names):
                    if node == "worker" and running(runs / run) and early(runs / run):
                        return run
                return None

            victim = wait_for("a run past a checkpoint on the second node", on_worker, poll=0.02)
            c.nodes["worker"].kill()
            stdout, stderr = driver.communicate(timeout=600)
        finally:
            if driver.poll() is None:
                driver.kill()
                driver.wait()
    assert driver.returncode == 0, stderr[-2000:]
    assert "2 runs finished, 0 failed" in stdout
    where = placement(runs, c.names)
    first = sorted((run, node) for run, i, _, node in where if i == 0)
    assert first in (
        [("alp-gmm__s0", "head"), ("random__s0", "worker")],
        [("alp-gmm__s0", "worker"), ("random__s0", "head")],
    ), where
    assert [node for run, _, _, node in where if run == victim][-1] == "head", where
    whats = [what for _, _, what in attempts(runs / victim)]
    assert whats[0] == "starting afresh" and whats[-1].startswith("resuming"), whats
    for run in ("alp-gmm__s0", "random__s0"):
        status = json.loads((runs / run / "status.json").read_text())
        assert status["status"] == "finished" and status["steps"] == STEPS
