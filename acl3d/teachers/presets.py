"""Named hyper-parameter sets: TeachMyAgent's benchmark values and teachDeepRL's defaults.

`BENCHMARK` equals the class defaults (the TeachMyAgent paper runs, §1.4 of the reference);
`TEACHDEEPRL` holds the teachDeepRL (CoRL 2019) values, used for the toy-environment comparison.
A teacher missing from a preset uses its class defaults. Facts of the environment (ADR's reward
thresholds, the Oracle's success threshold) are not hyper-parameters and are in no preset: a
training run takes them from the environment's `CurriculumProfile` (`Teacher.run_params`).
"""

from __future__ import annotations

from typing import Any

BENCHMARK: dict[str, dict[str, Any]] = {
    "random": {},
    "alp-gmm": {
        "fit_rate": 150,
        "nb_bootstrap": 150,
        "random_task_ratio": 0.05,
        "potential_ks": list(range(2, 10)),
    },
    "covar-gmm": {"fit_rate": 150, "random_task_ratio": 0.10, "potential_ks": list(range(2, 15))},
    "riac": {
        "max_region_size": 150,
        "alp_window_size": 150,
        "nb_split_attempts": 75,
        "min_region_size": 7.5,
        "min_dims_range_ratio": 0.1,
        "discard_ratio": 0.25,
    },
    "adr": {
        "step_size": 0.1,
        "boundary_sampling_p": 0.7,
        "queue_len": 10,
    },
    "oracle": {"step_rate": 50},
}

TEACHDEEPRL: dict[str, dict[str, Any]] = {
    "random": {},
    "alp-gmm": {
        "fit_rate": 250,
        "nb_bootstrap": 250,
        "random_task_ratio": 0.2,
        "potential_ks": list(range(2, 11)),
    },
    "covar-gmm": {"fit_rate": 250, "random_task_ratio": 0.2, "potential_ks": list(range(2, 11))},
    "riac": {
        "max_region_size": 200,
        "alp_window_size": 200,
        "nb_split_attempts": 50,
        "min_region_size": 10,
        "min_dims_range_ratio": 1 / 15,
        "discard_ratio": 0.25,
    },
    "oracle": {"step_rate": 50},
}

PRESETS: dict[str, dict[str, dict[str, Any]]] = {"benchmark": BENCHMARK, "teachdeeprl": TEACHDEEPRL}


def preset_params(preset: str, teacher: str) -> dict[str, Any]:
    """A copy of `teacher`'s parameters in `preset` ({} when the preset does not set any)."""
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; valid presets: {', '.join(PRESETS)}")
    return dict(PRESETS[preset].get(teacher, {}))
