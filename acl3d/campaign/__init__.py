"""Benchmark campaigns: YAML specs expanded into runs, executed on Ray or local processes.

`load_spec("quick").scaled(budget=0.1).expand()` lists the runs; `run_campaign(spec, out)` runs
them (continuing an interrupted campaign in the same directory). Each run is an ordinary run
directory under `out/runs/`, which `acl3d analyze` reads.
"""

from acl3d.campaign.options import parse_set
from acl3d.campaign.runner import CampaignDir, CampaignResult, run_campaign
from acl3d.campaign.spec import CampaignSpec, RunSpec, builtin_names, load_spec

__all__ = [
    "CampaignDir",
    "CampaignResult",
    "CampaignSpec",
    "RunSpec",
    "builtin_names",
    "load_spec",
    "parse_set",
    "run_campaign",
]
