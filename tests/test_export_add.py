"""`acl3d campaign export --add`: a protocol's shipped runs grown by a later campaign of the same
spec (other seeds, on another machine), the runs already there kept byte for byte."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
import yaml

from acl3d import provenance
from acl3d.analysis.curriculum_files import shipped_bytes
from acl3d.analysis.export import export_campaign
from acl3d.cli import main

SPEC = {"name": "mini", "base": {"steps": 256, "n_envs": 1}, "seeds": [0], "only": {},
        "grid": {"teacher": {"random": {"teacher": "random"}}}}  # fmt: skip


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory) -> Path:
    """One real finished run (SB3 PPO, 256 steps), copied into the campaigns below."""
    from acl3d.training import train

    run_dir = tmp_path_factory.mktemp("trained") / "run"
    train(teacher="random", student="ppo", preset="fast", steps=256, n_envs=1, vec_env="dummy",
          nb_test_episodes=4, eval_every=128, env_kwargs={"max_episode_steps": 30},
          student_params={"n_steps": 128, "batch_size": 64, "n_epochs": 1}, progress_bar=False,
          verbose=0, out=str(run_dir))  # fmt: skip
    return run_dir


ORACLE = {"teacher": "oracle", "teacher_params": {"step_rate": 50}}
GROWN = {"teacher": {"random": {"teacher": "random"}, "oracle": ORACLE}}  # a label added
RANDOM_RESEEDED = {"teacher": {"random": {"teacher": "random", "teacher_params": {"x": 1}}}}
ORACLE_ONLY = {"teacher": {"oracle": ORACLE}}  # random dropped


def _campaign(root: Path, run: Path, seed: int, **spec_changes) -> Path:
    """A campaign directory of one finished cell, `random__s{seed}`, under `SPEC` changed."""
    name = f"random__s{seed}"
    shutil.copytree(run, root / "runs" / name)
    spec = {**SPEC, "seeds": [seed], **spec_changes}
    entry = {"name": name, "labels": {"teacher": "random", "seed": seed}}
    (root / "campaign.yaml").write_text(yaml.safe_dump({"spec": spec, "runs": [entry]}))
    return root


def _export(camp: Path, out: Path, *extra: str) -> int:
    return main(["campaign", "export", str(camp), "--protocol", "mini", "--out", str(out), *extra])


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_add_keeps_the_runs_exported_before_and_records_both(tmp_path, trained_run):
    first = _campaign(tmp_path / "a", trained_run, 0)
    second = _campaign(tmp_path / "b", trained_run, 1)
    provenance.close(second / "runs" / "random__s1", "interrupted", 128)  # stopped, resumed
    provenance.record(second / "runs" / "random__s1", "resume", step=128, device="cpu")
    out = tmp_path / "exported"
    assert _export(first, out) == 0
    before = _tree(out / "random__s0")
    assert _export(second, out, "--add") == 0
    assert _tree(out / "random__s0") == before  # kept byte for byte
    doc = yaml.safe_load((out / "protocol.yaml").read_text())
    assert sorted(doc["runs"]) == ["random__s0", "random__s1"]
    assert doc["spec"]["seeds"] == [0, 1] and doc["planned_runs"] == {"random": 1}
    assert doc["resumed"] == {"random__s1": 1} and doc["bytes"] == shipped_bytes(out) - len(
        (out / "protocol.yaml").read_bytes()
    )
    assert len(list(out.glob("random__s*/evals.csv"))) == 2
    # without --add the export replaces the folder as a whole, as before
    assert _export(second, out) == 0
    assert sorted(yaml.safe_load((out / "protocol.yaml").read_text())["runs"]) == ["random__s1"]


@pytest.mark.parametrize(
    "setup, message",
    [
        (lambda tmp, run: _campaign(tmp / "c", run, 1, base={"steps": 512, "n_envs": 1}),
         "another spec.*base differ"),
        (lambda tmp, run: _campaign(tmp / "c", run, 1, name="other"), "name differ"),
        (lambda tmp, run: _campaign(tmp / "c", run, 1, grid=RANDOM_RESEEDED), "grid differ"),
        (lambda tmp, run: _campaign(tmp / "c", run, 1, grid=ORACLE_ONLY), "grid differ"),
    ],
)  # fmt: skip
def test_add_refuses_runs_of_another_spec_and_changes_nothing(tmp_path, capsys, trained_run,
                                                              setup, message):  # fmt: skip
    out = tmp_path / "exported"
    assert _export(_campaign(tmp_path / "a", trained_run, 0), out) == 0
    before = _tree(out)
    assert _export(setup(tmp_path, trained_run), out, "--add") == 2
    assert re.search(message, capsys.readouterr().err)
    assert _tree(out) == before


PINNED = {"steps": 256, "n_envs": 1, "student": "rsl-ppo", "student_params": {"gamma": 0.99}}


@pytest.mark.parametrize("floor, taken", [(0.0, True), (0.3, False)])
def test_add_takes_a_spec_that_pins_a_parameter_added_since_at_its_earlier_value(
    tmp_path, capsys, trained_run, floor, taken
):
    """rsl-ppo's `min_noise_std` came after runs that pinned its other parameters: pinned at 0
    (no floor, what those runs trained with) it is the same spec; at 0.3 another one."""
    out = tmp_path / "exported"
    assert _export(_campaign(tmp_path / "a", trained_run, 0, base=PINNED), out) == 0
    before = _tree(out)
    pinned = {**PINNED, "student_params": {**PINNED["student_params"], "min_noise_std": floor}}
    code = _export(_campaign(tmp_path / "b", trained_run, 1, base=pinned), out, "--add")
    doc = yaml.safe_load((out / "protocol.yaml").read_text())
    if taken:
        assert code == 0 and sorted(doc["runs"]) == ["random__s0", "random__s1"]
        assert doc["spec"]["base"] == pinned  # the spec as pinned now
    else:
        assert code == 2 and re.search("another spec.*base differ", capsys.readouterr().err)
        assert _tree(out) == before


def test_add_takes_a_campaign_whose_grid_adds_labels_and_records_the_grown_grid(
    tmp_path, trained_run
):
    out = tmp_path / "exported"
    assert _export(_campaign(tmp_path / "a", trained_run, 0), out) == 0
    before = _tree(out / "random__s0")
    assert _export(_campaign(tmp_path / "b", trained_run, 1, grid=GROWN), out, "--add") == 0
    assert _tree(out / "random__s0") == before
    doc = yaml.safe_load((out / "protocol.yaml").read_text())
    assert sorted(doc["runs"]) == ["random__s0", "random__s1"]
    assert doc["spec"]["grid"] == GROWN and doc["spec"]["seeds"] == [0, 1]


def test_add_needs_an_export_of_the_same_protocol(tmp_path, capsys, trained_run):
    camp = _campaign(tmp_path / "a", trained_run, 0)
    assert _export(camp, tmp_path / "nothing-yet", "--add") == 2
    assert "holds no export to add runs to" in capsys.readouterr().err
    assert not (tmp_path / "nothing-yet").exists()
    other = tmp_path / "other"
    assert main(["campaign", "export", str(camp), "--protocol", "mini-2", "--out", str(other)]) == 0
    assert _export(camp, other, "--add") == 2
    assert "an export of protocol 'mini-2', not 'mini'" in capsys.readouterr().err


def test_an_export_that_fails_on_the_way_leaves_the_earlier_one_as_it_was(tmp_path, trained_run):
    out = tmp_path / "exported"
    assert _export(_campaign(tmp_path / "a", trained_run, 0), out) == 0
    before = _tree(out)
    broken = _campaign(tmp_path / "b", trained_run, 1)
    (broken / "runs" / "random__s1" / "evals_tasks.csv").unlink()  # read after others are written
    for add in (False, True):
        with pytest.raises(FileNotFoundError):
            export_campaign(broken, out, "mini", add=add, spec=SPEC)
        assert _tree(out) == before
        assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b", "exported"]


def test_a_planned_run_with_no_evaluation_yet_is_named_as_left_out(tmp_path, trained_run):
    camp = _campaign(tmp_path / "a", trained_run, 0)
    started = camp / "runs" / "random__s1"  # running: its config written, no evaluation yet
    shutil.copytree(trained_run, started)
    header = (started / "evals.csv").read_text().splitlines()[0]
    (started / "evals.csv").write_text(header + "\n")
    (started / "status.json").write_text('{"status": "running"}')
    doc = yaml.safe_load((camp / "campaign.yaml").read_text())
    # s1 started, s2 planned and never started
    doc["runs"] += [
        {"name": f"random__s{s}", "labels": {"teacher": "random", "seed": s}} for s in (1, 2)
    ]
    (camp / "campaign.yaml").write_text(yaml.safe_dump(doc))
    out = tmp_path / "exported"
    assert _export(camp, out) == 0
    exported = yaml.safe_load((out / "protocol.yaml").read_text())
    assert exported["runs"] == ["random__s0"]
    assert exported["left_out"] == ["random__s1", "random__s2"]
