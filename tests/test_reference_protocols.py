"""The versioned reference protocols (stump-v1, parkour-walker-v1, v2 and stump-rsl on the
torch-native student): complete, pinned, buildable."""

from __future__ import annotations

import inspect

import pytest

from acl3d import results
from acl3d.campaign import load_spec
from acl3d.campaign.spec import check_runs
from acl3d.teachers import teacher_class
from acl3d.training.students import hyperparameters

STUMP_TEACHERS = {
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
}
PROTOCOLS = {
    "stump-v1": STUMP_TEACHERS,
    "parkour-walker-v1": {"random", "alp-gmm", "covar-gmm", "riac"},
    "stump-v2": STUMP_TEACHERS,  # those that learn from every step included
    "parkour-walker-v2": {"random", "alp-gmm", "covar-gmm", "riac", "terrain-levels"},
    "stump-rsl": {"random", "alp-gmm", "terrain-levels", "oracle"},
    "stump-rsl-10m": {
        "random",
        "alp-gmm",
        "terrain-levels",
        "oracle",
        "robust-plr",
        "covar-gmm",
        "riac",
        "adr",
    },
}


@pytest.mark.parametrize("name", sorted(PROTOCOLS))
def test_protocol_runs_every_teacher_with_pinned_parameters(name):
    spec = load_spec(name)
    runs = spec.expand()
    assert {r.labels["teacher"] for r in runs} == PROTOCOLS[name]
    if name.endswith("-v1"):
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


@pytest.mark.parametrize("name", ["stump-v2", "parkour-walker-v2"])
def test_v2_seeds_budget_and_path(name):
    runs = load_spec(name).expand()
    seeds: dict[str, set] = {}
    for run in runs:
        seeds.setdefault(run.labels["teacher"], set()).add(run.labels["seed"])
    for teacher, got in seeds.items():
        assert got == set(range(16 if teacher in ("random", "alp-gmm") else 8)), teacher
    for run in runs:
        assert run.options["student"] == "rsl-ppo" and run.options["steps"] == 20_000_000
    path = {(r.options["device"], r.options["vec_env"], r.options["n_envs"]) for r in runs}
    assert path == {("cuda", "auto", 4096)}
    spec = load_spec(name)
    assert "provisional" in spec.description
    # the description says how far the protocol has run: shipped runs make it "partly run"
    state = "partly run" if name in results.protocols() else "not run yet"
    assert state in spec.description, (name, state)


@pytest.mark.parametrize("name", ["stump-v2", "parkour-walker-v2"])
def test_v2_specs_pass_the_checks_a_run_makes(name):
    """Every run's options as `train` checks them; a machine without a GPU checks stump-v2
    with --set device=cpu (cluster submissions leave the device to the node)."""
    spec = load_spec(name)
    check_runs(spec.expand(), on_this_machine=False)
    check_runs(spec.scaled(sets={"device": "cpu"}).expand())


def test_stump_rsl_10m_is_stump_rsl_at_five_times_the_budget_with_the_noise_floor():
    """The same task space, test grid, body, worlds, student and teachers as pinned in
    stump-rsl, and Robust PLR, Covar-GMM, RIAC and ADR as pinned in stump-v1; only the budget,
    its evaluation and sampling cadence and the floor differ."""
    short, long = load_spec("stump-rsl"), load_spec("stump-rsl-10m")
    changed = {"steps": 10_000_000, "eval_every": 2_000_000, "periodical_samples_every": 1_000_000}
    assert {k: long.base[k] for k in changed} == changed
    assert {k: v for k, v in long.base.items() if k not in changed and k != "student_params"} == {
        k: v for k, v in short.base.items() if k not in changed and k != "student_params"
    }
    params = dict(short.base["student_params"], min_noise_std=0.3)
    assert long.base["student_params"] == params
    v1 = load_spec("stump-v1").grid["teacher"]
    added = {name: v1[name] for name in ("robust-plr", "covar-gmm", "riac", "adr")}
    assert long.grid["teacher"] == {**short.grid["teacher"], **added}
    assert list(long.seeds) == list(range(8))
    check_runs(long.expand())
