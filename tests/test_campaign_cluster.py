"""A campaign submitted with `--address` to a real Ray cluster: a head and a second node started
as separate `ray start` processes with their own CPU; the runs go to both nodes.

A node killed mid-campaign and a killed campaign process take minutes to show on real runs:
scripts/ray_cluster_check.py checks them (every run finished once, results equal to a local
campaign)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from acl3d.campaign import load_spec, run_campaign

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from ray_cluster_check import SETS, cluster, placement  # noqa: E402

TINY = {**SETS, "steps": 256}  # one 256-step rollout per run


def test_campaign_runs_on_both_nodes_of_a_ray_cluster(tmp_path):
    spec = load_spec("quick").scaled(seeds=1, sets=TINY)
    out = tmp_path / "camp"
    with cluster(tmp_path) as (address, _, names):
        result = run_campaign(spec, out, executor="ray", address=address, live=False)
    assert sorted(result.finished) == ["alp-gmm__s0", "random__s0"] and not result.failed
    where = placement(out / "runs", names)
    assert sorted(node for *_, node in where) == ["head", "worker"], where
    for run in result.finished:
        status = json.loads((out / "runs" / run / "status.json").read_text())
        assert status["status"] == "finished" and status["steps"] == 256
