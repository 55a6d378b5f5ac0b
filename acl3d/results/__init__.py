"""Committed reference results: the runs of each versioned protocol, as package data.

`acl3d/results/<protocol>/` holds `protocol.yaml` (the campaign spec, budget, hardware, when
exported) and one folder per run (`<teacher>__s<seed>/`): `config.yaml` (the run's config,
effective student hyper-parameters and task space), `evals.csv` (% mastered and mean return at
every evaluation), `evals_tasks.csv` (return, length and success of every test task at every
evaluation), `test_set.csv` (the test tasks), `episodes_summary.csv` (training episodes in 20
windows of the budget: count, return, length, success, mean task) and `status.json`; protocols
exported since v2 add `episodes.npz` (every training episode), `teacher.json`/`teacher.npz` (the
teacher's dump) and `provenance.json` (`acl3d.analysis.curriculum_files`). No models.
`acl3d campaign export` writes this form; `acl3d analyze RUNS --reference <protocol>` reads it.
This package holds data only: it imports nothing from acl3d.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def protocols() -> list[str]:
    """Names of the protocols whose results ship with this install."""
    root = resources.files(__name__)
    return sorted(p.name for p in root.iterdir() if p.is_dir() and (p / "protocol.yaml").is_file())


def path(protocol: str) -> Path:
    """The folder of a shipped protocol's results."""
    shipped = protocols()
    if protocol not in shipped:
        raise ValueError(
            f"reference {protocol!r}: not a shipped protocol ({', '.join(shipped) or 'none'}) "
            "nor a folder of runs"
        )
    return Path(str(resources.files(__name__) / protocol))
