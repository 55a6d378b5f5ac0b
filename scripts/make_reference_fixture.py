"""Regenerate tests/data/reference-mini: a tiny real campaign in the committed results' form.

Two campaigns of stump-v1 shrunk to seconds per run (1024 steps on 2 envs, 40-step episodes, a
2 x 2 test grid, two evaluations): the "reference" (Random, ALP-GMM, RIAC x 3 seeds), exported
with `acl3d campaign export` into tests/data/reference-mini/, and the "new teacher" runs
(Covar-GMM x 3 seeds), exported into tests/data/reference-mini-new/. tests/test_reference_results.py
analyses them; nothing in them is hand-written.

    python scripts/make_reference_fixture.py        # ~2 min on 2 cores
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from acl3d.analysis.export import export_campaign
from acl3d.campaign import CampaignSpec, load_spec, run_campaign

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"
TINY = {
    "steps": 1024,
    "n_envs": 2,
    "vec_env": "dummy",
    "eval_every": 512,
    "periodical_samples_every": 512,
    "nb_test_episodes": 4,
    "env_kwargs": {"max_episode_steps": 40},
    "progress_bar": False,
    "verbose": 0,
}
STUDENT = {"n_steps": 256, "batch_size": 128, "n_epochs": 1}


def tiny_spec(name: str, teachers: list[str]) -> CampaignSpec:
    doc = load_spec("stump-v1").to_dict()
    doc["name"] = name
    doc["base"].update(TINY)
    doc["base"]["student_params"].update(STUDENT)
    doc["grid"]["teacher"] = {t: doc["grid"]["teacher"][t] for t in teachers}
    doc["seeds"] = 3
    return CampaignSpec.from_dict(doc)


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        for name, teachers in (
            ("reference-mini", ["random", "alp-gmm", "riac"]),
            ("reference-mini-new", ["covar-gmm"]),
        ):
            camp = Path(tmp) / name
            result = run_campaign(tiny_spec(name, teachers), camp, executor="local", live=False)
            if result.failed:
                print(f"failed runs: {result.failed}", file=sys.stderr)
                return 1
            names = export_campaign(camp, DATA / name, name)
            print(f"{name}: {len(names)} runs exported")
    return 0


if __name__ == "__main__":
    sys.exit(main())
