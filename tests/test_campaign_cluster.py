"""A campaign submitted with `--address` to a real Ray cluster: a head and a second node started
as separate `ray start` processes with their own CPU; the runs go to both nodes.

A node killed mid-campaign and a killed campaign process take minutes to show on real runs:
scripts/ray_cluster_check.py checks them (every run finished once, results equal to a local
campaign)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from ray_cluster_check import SETS, campaign_cmd, cluster, placement  # noqa: E402

TINY = {**SETS, "steps": 256}  # one 256-step rollout per run


def test_campaign_runs_on_both_nodes_of_a_ray_cluster(tmp_path):
    out = tmp_path / "camp"
    with cluster(tmp_path) as c:
        submit = campaign_cmd(out, "--address", c.address, seeds=1, sets=TINY)
        proc = subprocess.run(submit, env=c.env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "2 runs finished, 0 failed" in proc.stdout
    where = placement(out / "runs", c.names)
    assert sorted((run, node) for run, _, _, node in where) in (
        [("alp-gmm__s0", "head"), ("random__s0", "worker")],
        [("alp-gmm__s0", "worker"), ("random__s0", "head")],
    ), where
    for run in ("alp-gmm__s0", "random__s0"):
        status = json.loads((out / "runs" / run / "status.json").read_text())
        assert status["status"] == "finished" and status["steps"] == 256
