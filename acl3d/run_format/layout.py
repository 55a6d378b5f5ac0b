"""The names of a run directory's files (see the package docstring for what each holds)."""

from __future__ import annotations

CONFIG_YAML = "config.yaml"
CONFIG_JSON = "config.json"
PROVENANCE = "provenance.json"
STATUS = "status.json"
EVALS = "evals.csv"
EVALS_TASKS = "evals_tasks.csv"
EPISODES = "episodes.csv"
TEACHER = "teacher"  # prefix of teacher.json + teacher.npz
TENSORBOARD = "tb"
CHECKPOINTS = "checkpoints"
LATEST = "LATEST"  # inside checkpoints/
MANIFEST = "manifest.json"  # inside each checkpoint
FINAL_MODEL = "final_model.zip"

# What `acl3d train` writes in a run directory: `--overwrite` removes these and nothing else.
RUN_ENTRIES = (
    CONFIG_YAML, CONFIG_JSON, PROVENANCE, STATUS, EVALS, EVALS_TASKS, EPISODES,
    f"{TEACHER}.json", f"{TEACHER}.npz", TENSORBOARD, CHECKPOINTS, FINAL_MODEL,
    "final_model_vecnormalize.json", "final_model_vecnormalize.npz",
)  # fmt: skip
