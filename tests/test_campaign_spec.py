"""Campaign specs: expansion into named runs, --budget / --seeds / --set, bad input, the CLI."""

import pytest

from acl3d.campaign import CampaignSpec, builtin_names, load_spec, parse_set
from acl3d.cli import main


def test_builtin_specs_expand():
    assert set(builtin_names()) >= {"quick", "stump-ppo", "terrain3d", "tma-parkour", "tma-skills"}
    quick = load_spec("quick").expand()
    assert [r.name for r in quick] == ["random__s0", "random__s1", "alp-gmm__s0", "alp-gmm__s1"]
    assert quick[2].options["teacher"] == "alp-gmm" and quick[2].options["seed"] == 0
    assert quick[0].options["student"] == "ppo" and quick[0].options["preset"] == "fast"

    skills = load_spec("tma-skills").expand()
    # 8 teachers x (4 criteria + 4 student variants) x 3 levels x 16 seeds, Random at one level
    assert len(skills) == 8 * 8 * 3 * 16 - 2 * 8 * 16
    by_name = {r.name: r for r in skills}
    unfeasible = by_name["alp-gmm__mostly-unfeasible__ek-high__s3"]
    assert unfeasible.options["bounds"]["stump_height"] == [0.0, 9.0]
    assert unfeasible.labels["criterion"] == "mostly-unfeasible"
    spider = by_name["riac__variety-of-students-spider-ppo__ek-no__s0"]
    assert (spider.options["body"], spider.options["student"]) == ("spider", "ppo")
    assert spider.labels["variant"] == "spider-ppo" and spider.labels["body"] == "spider"
    assert not any(r.labels["teacher"] == "random" and r.labels["expert_knowledge"] != "low"
                   for r in skills)  # fmt: skip

    parkour = {r.name: r for r in load_spec("tma-parkour").expand()}
    assert len(parkour) == 8 * 3 * 16
    fish = parkour["covar-gmm__fish__s15"]
    assert fish.options["body"] == "fish" and fish.options["test_set"] == "swimming"


def test_budget_seeds_and_set():
    spec = load_spec("tma-skills").scaled(budget=0.05, seeds=2)
    runs = {r.name: r for r in spec.expand()}
    forgetting = runs["adr__forgetting-student__ek-low__s1"].options
    assert forgetting["steps"] == 1_000_000 and forgetting["reset_student_every"] == 350_000
    assert forgetting["eval_every"] == 25_000
    assert {r.labels["seed"] for r in runs.values()} == {0, 1}

    sets = parse_set(["steps=4096", "n_envs=2", "nb_test_episodes=4", "teacher=riac"])
    quick = load_spec("quick").scaled(budget=3, seeds=1, sets=sets).expand()
    assert [r.name for r in quick] == ["s0"]  # the teacher axis is replaced by --set
    assert quick[0].options["steps"] == 4096  # --set is not scaled by --budget
    assert quick[0].options["teacher"] == "riac" and quick[0].options["n_envs"] == 2
    assert parse_set(["steps=2e6", "bounds={stump_height: [0, 9]}"]) == {
        "steps": 2_000_000,
        "bounds": {"stump_height": [0, 9]},
    }


@pytest.mark.parametrize(
    "item, message",
    [
        ("stepz=3", "unknown training option 'stepz'"),
        ("steps=abc", "option 'steps' must be of type int"),
        ("steps=true", "option 'steps' must be of type int"),
        ("steps=1.5", "option 'steps' must be of type int"),
        ("shuffle_dimensions=1", "option 'shuffle_dimensions' must be of type bool"),
        ("out=/tmp/x", "'out' is set by the campaign"),
        ("seed=3", "'seed' is set by the campaign"),
        ("steps", "expected KEY=VALUE"),
        ("steps=", "option 'steps' must be of type int, got None"),
        ("bounds={a: [", "not valid YAML"),
    ],
)
def test_bad_set_values_are_rejected(item, message):
    with pytest.raises(ValueError, match=message):
        parse_set([item])


def test_bad_specs_and_scaling_are_rejected():
    good = {"name": "x", "grid": {"teacher": ["random"]}}
    for bad, message in [
        ({**good, "gird": {}}, "unknown key"),
        ({**good, "seeds": 0}, "seeds"),
        ({**good, "seeds": [1, 1]}, "distinct"),
        ({**good, "grid": {"teacher": []}}, "at least one value"),
        ({**good, "base": {"n_env": 2}}, "unknown training option 'n_env'"),
        ({**good, "grid": {"c": {"p": {"steps": "many"}}}}, "'steps' must be of type int"),
        ({**good, "grid": {"seed": [1, 2]}}, "set by the campaign"),
    ]:
        with pytest.raises(ValueError, match=message):
            CampaignSpec.from_dict(bad)
    spec = CampaignSpec.from_dict(good)
    for budget in (0, -1, float("nan"), True, "2"):
        with pytest.raises(ValueError, match="budget"):
            spec.scaled(budget=budget)
    with pytest.raises(ValueError, match="not a built-in"):
        load_spec("no-such-spec")


def test_exclude_rules():
    spec = CampaignSpec.from_dict(
        {
            "name": "x",
            "grid": {"teacher": ["random", "adr"], "expert_knowledge": ["no", "high"]},
            "exclude": [{"teacher": "adr", "expert_knowledge": "no"}],
        }
    )
    assert [r.name for r in spec.expand()] == [
        "random__ek-no__s0",
        "random__ek-high__s0",
        "adr__ek-high__s0",
    ]


def test_cli_list_show_and_errors(capsys):
    assert main(["campaign", "list"]) == 0
    assert "tma-skills" in capsys.readouterr().out
    assert main(["campaign", "show", "quick", "--set", "steps=4096", "--seeds", "1"]) == 0
    out = capsys.readouterr().out
    assert "# 2 runs, 8,192 steps in all" in out and "alp-gmm__s0" in out
    assert main(["campaign", "run", "quick", "--out", "/nonexistent/x", "--set", "nope=1"]) == 2
    assert "unknown training option 'nope'" in capsys.readouterr().err


def test_an_exclude_rule_with_lists_matches_any_of_their_values():
    spec = CampaignSpec.from_dict(
        {
            "name": "x",
            "grid": {"teacher": ["random", "alp-gmm", "riac"]},
            "seeds": 4,
            # fewer seeds for RIAC and ALP-GMM; a rule of single values as before
            "exclude": [{"teacher": ["riac", "alp-gmm"], "seed": [2, 3]},
                        {"teacher": "alp-gmm", "seed": 0}],
        }
    )  # fmt: skip
    names = [r.name for r in spec.expand()]
    assert names == ["random__s0", "random__s1", "random__s2", "random__s3", "alp-gmm__s1",
                     "riac__s0", "riac__s1"]  # fmt: skip
