"""The versioned reference protocols (stump-v1, parkour-walker-v1): complete, pinned, buildable."""

from __future__ import annotations

import inspect

import pytest

from acl3d.campaign import load_spec
from acl3d.teachers import teacher_class
from acl3d.training.students import hyperparameters

PROTOCOLS = {
    "stump-v1": {
        "random",
        "alp-gmm",
        "covar-gmm",
        "riac",
        "adr",
        "self-paced",
        "goal-gan",
        "setter-solver",
        "robust-plr",
        "accel",
        "terrain-levels",
        "oracle",
    },
    "parkour-walker-v1": {"random", "alp-gmm", "covar-gmm", "riac"},
}


@pytest.mark.parametrize("name", sorted(PROTOCOLS))
def test_protocol_runs_every_teacher_with_pinned_parameters(name):
    spec = load_spec(name)
    runs = spec.expand()
    assert {r.labels["teacher"] for r in runs} == PROTOCOLS[name]
    assert len(spec.seeds) >= 4 and len(runs) == len(PROTOCOLS[name]) * len(spec.seeds)
    for run in runs:
        options = run.options
        # every student hyper-parameter written out, not left to the preset
        preset = hyperparameters(options["student"], options["preset"], options["n_envs"])
        assert set(options["student_params"]) == set(preset)
        for key in ("steps", "eval_every", "test_set", "nb_test_episodes", "expert_knowledge"):
            assert options[key] is not None
        # and every teacher parameter is one its class takes
        signature = inspect.signature(teacher_class(options["teacher"]).__init__)
        unknown = set(options.get("teacher_params", {})) - set(signature.parameters)
        assert not unknown, f"{run.name}: unknown teacher parameters {unknown}"
