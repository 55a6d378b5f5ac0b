"""Mistakes refused up front with one line naming the option: bounds beyond what the env can
build (an `--overwrite` then keeps the old run), a torn config.yaml under `evaluate`, resource
bounds (test sets, networks, episodes, replicates), over-long names, malformed files, and the
usage and naming slips of the command line and the Python API."""

from __future__ import annotations

import json
import os
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml
from cli_support import one_line_error

from acl3d.cli import main
from acl3d.teachers import teacher_class, test_sets
from acl3d.training import TrainConfig

TINY = [
    "--teacher", "random", "--student", "ppo", "--n-envs", "2", "--nb-test-episodes", "4",
    "--env-kwarg", "max_episode_steps=50", "--student-param", "n_steps=128",
    "--student-param", "batch_size=128", "--steps", "512", "--no-progress", "--quiet",
]  # fmt: skip


def fake_run(path: Path, cut: str | None = None) -> Path:
    """A run directory as train writes it (config.yaml with its sections, a checkpoint and a
    final model), without training; `cut` tears config.yaml where that text starts."""
    config = TrainConfig(teacher="random", out=str(path))
    doc = {"config": config.to_dict(), "student_hyperparameters": {}, "resolved": {"steps": 512}}
    text = yaml.safe_dump(doc, sort_keys=False)
    (path / "checkpoints" / "step_000000000512").mkdir(parents=True)
    (path / "checkpoints" / "step_000000000512" / "model.zip").write_bytes(b"weights")
    (path / "final_model.zip").write_bytes(b"final weights")
    (path / "config.yaml").write_text(text[: text.index(cut)] if cut else text)
    return path


def snapshot(run: Path) -> dict[str, bytes]:
    return {str(p.relative_to(run)): p.read_bytes() for p in run.rglob("*") if p.is_file()}


# ---------------------------------------------------------------------- 1: bounds, --overwrite
@pytest.mark.parametrize("bounds", ["stump_height=0,100", "stump_height=0,19.4"])
def test_bounds_beyond_the_buildable_range_keep_the_run_overwrite_would_delete(
    bounds, tmp_path, capsys
):
    run = fake_run(tmp_path / "run")
    before = snapshot(run)
    argv = ["train", *TINY, "--bounds", bounds, "--out", str(run), "--overwrite"]
    assert main(argv) == 2
    one_line_error(capsys, f"--bounds stump_height=[0.0, {bounds.split(',')[1]}", "19.2857")
    assert snapshot(run) == before


# ---------------------------------------------------------------------- 2: torn config.yaml
def test_evaluate_refuses_a_torn_config_as_resume_does(tmp_path, capsys):
    run = fake_run(tmp_path / "run", cut="  eval_every:")  # as `head -c` of a whole line
    assert main(["evaluate", str(run)]) == 2
    one_line_error(capsys, "config.yaml lacks config field(s)", "eval_stochastic")


def test_a_config_recorded_before_an_option_existed_still_loads():
    """Runs written before `eval_together` existed lack it (they played every evaluation when
    due); any other missing field is still a torn file."""
    from acl3d.training.config import TrainConfig

    recorded = TrainConfig(eval_every=1000).to_dict()
    del recorded["eval_together"]
    assert TrainConfig.recorded(recorded, "old.yaml").eval_together is None
    del recorded["eval_every"]
    with pytest.raises(ValueError, match=r"old.yaml lacks config field\(s\) \['eval_every'\]"):
        TrainConfig.recorded(recorded, "old.yaml")


# ---------------------------------------------------------------------- 4: resource bounds
def test_test_set_file_over_the_cap_and_malformed_json_name_file_and_option(tmp_path, capsys):
    space = gym.make("acl3d/StumpTracks-v0").unwrapped.task_space
    big = tmp_path / "big.json"
    rows = [[1.0, 2.0]] * (test_sets.MAX_TASKS + 1)
    big.write_text(json.dumps({"names": space.flat_names(), "tasks": rows}))
    with pytest.raises(ValueError, match=r"100001 tasks; valid: at most 100000"):
        test_sets.load(big, space)
    bad = tmp_path / "bad.json"
    bad.write_text('[{"stump_height": 1.0,\n')
    assert main(["train", *TINY, "--test-set", str(bad), "--out", str(tmp_path / "r")]) == 2
    one_line_error(capsys, f"--test-set='{bad}': not valid JSON", "line 2")
    assert not (tmp_path / "r").exists()


def test_a_network_too_large_for_memory_is_refused(tmp_path, capsys):
    arch = "policy_kwargs={net_arch: [65536, 65536, 65536]}"
    out = tmp_path / "run"
    assert main(["train", *TINY, "--student-param", arch, "--out", str(out)]) == 2
    one_line_error(capsys, "net_arch", "weights between hidden layers")
    assert not out.exists()


def test_episode_and_replicate_counts_are_bounded(tmp_path, capsys):
    from acl3d.cli.evaluate import check_episodes

    with pytest.raises(ValueError, match=r"--episodes=100000; valid: an integer in \[1, 25000\]"):
        check_episodes(100_000, 4)
    check_episodes(25_000, 4)
    assert main(["render", "--episodes", "1000000000", "--out", str(tmp_path / "x.mp4")]) == 2
    one_line_error(capsys, "--episodes=1000000000; valid: an integer in [1, 1000]")
    assert main(["analyze", str(tmp_path), "--reps", "1000000000000"]) == 2
    one_line_error(capsys, "reps=1000000000000; valid")
    assert not list(tmp_path.iterdir())


def test_analyze_names_its_seed_replicates_and_out_as_typed(tmp_path, capsys):
    assert main(["analyze", str(tmp_path), "--seed", "-1"]) == 2
    one_line_error(capsys, "--seed=-1; valid: an integer >= 0")
    assert main(["analyze", str(tmp_path), "--reps", "5"]) == 2
    one_line_error(capsys, "--reps=5; valid: an integer in [100, 200000]")
    assert not list(tmp_path.iterdir())
    (tmp_path / "notes.txt").write_text("a file where a folder is meant")
    assert main(["analyze", str(tmp_path), "--out", str(tmp_path / "notes.txt" / "r")]) == 2
    one_line_error(capsys, "--out=", "cannot be created", "is a file")


# ---------------------------------------------------------------------- 6: names
def test_an_out_name_too_long_for_the_filesystem_is_one_line(tmp_path, capsys):
    out = tmp_path / ("x" * 300)
    assert main(["train", *TINY, "--out", str(out)]) == 2
    one_line_error(capsys, "--out=", "at most 255 bytes")


# ---------------------------------------------------------------------- 7: no tracebacks
def test_config_file_mapping_of_another_type_is_one_line(tmp_path, capsys):
    config = tmp_path / "c.yaml"
    config.write_text("env_kwargs: [1, 2]\n")
    argv = ["train", "--config", str(config), "--env-kwarg", "max_episode_steps=50"]
    assert main([*argv, "--out", str(tmp_path / "r")]) == 2
    one_line_error(capsys, f"--config file '{config}'", "env_kwargs=[1, 2]")


def test_curriculum_animation_of_a_truncated_teacher_dump_is_one_line(tmp_path, capsys):
    run = fake_run(tmp_path / "run")
    (run / "episodes.csv").write_text(
        "step,worker,return,length,success,truncated,stump_height,obstacle_spacing\n"
        "78,1,-106.9,39,0,0,0.12,0.10\n"
    )
    (run / "teacher.json").write_text('{"arrays": ["x"]}')
    (run / "teacher.npz").write_bytes(b"PK\x03\x04 cut")
    out = tmp_path / "c.gif"
    assert main(["render", "--curriculum", str(run), "--out", str(out)]) == 2
    one_line_error(capsys, "teacher.json/.npz cannot be read")
    assert not out.exists()


def test_resume_on_a_read_only_mount_is_refused_before_building(tmp_path, capsys, monkeypatch):
    run = fake_run(tmp_path / "run")
    before = snapshot(run)
    real_access = os.access
    monkeypatch.setattr(  # a read-only mount: access(2) says EROFS, even to root
        os, "access", lambda p, mode: not (mode & os.W_OK) and real_access(p, mode)
    )
    assert main(["train", "--resume", str(run)]) == 2
    one_line_error(capsys, "--resume=", "read-only")
    assert snapshot(run) == before


# ---------------------------------------------------------------------- 11: analyze's report
def test_analyze_of_the_shipped_results_writes_under_the_current_directory(tmp_path, monkeypatch):
    from acl3d import results
    from acl3d.cli import analyze as analyze_cli

    shipped = Path(results.__file__).parent / "stump-v1"
    monkeypatch.chdir(tmp_path)
    assert analyze_cli.default_out(shipped) == tmp_path / "report_stump-v1"
    assert analyze_cli.default_out(tmp_path / "campaign") is None  # beside its runs
    written = []
    monkeypatch.setattr("acl3d.analysis.analyze", lambda root, out, *a: written.append(out) or out)
    assert main(["analyze", str(shipped)]) == 0
    assert written == [tmp_path / "report_stump-v1"]


# ---------------------------------------------------------------------- also
def test_an_env_whose_first_reset_was_refused_resets_and_steps():
    env = gym.make("acl3d/StumpTracks-v0")
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"foo": 1})
    env.reset(seed=0)
    assert np.isfinite(env.step(np.zeros(4))[1])


def test_a_time_limit_below_one_step_is_refused_in_acl3ds_words():
    from acl3d.envs import make

    with pytest.raises(ValueError, match=r"max_episode_steps=0; valid: an integer in \[1,"):
        make("stump-tracks", max_episode_steps=0)


def test_make_vec_sync_with_a_teacher_points_to_the_vector_entry_point():
    with pytest.raises(TypeError, match='vectorization_mode="vector_entry_point", teacher='):
        gym.make_vec("acl3d/StumpTracks-v0", 2, vectorization_mode="sync", teacher=object())


def test_unknown_train_option_prints_trains_usage(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["train", "--task", "stump_height=1"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.startswith("usage: acl3d train")
    assert "acl3d train: error: unrecognized arguments: --task" in err


def test_a_misspelt_teacher_gets_did_you_mean():
    with pytest.raises(ValueError, match=r"unknown teacher 'alp_gmm' \(did you mean 'alp-gmm'\?\)"):
        teacher_class("alp_gmm")


@pytest.mark.parametrize("student", ["ppo", "rsl-ppo"])
def test_a_refused_run_says_nothing_about_its_steps_first(student, tmp_path, capsys):
    """The note that steps round up to whole rollouts comes once the run's checks passed: a
    refused run prints its error alone."""
    if student == "rsl-ppo":
        pytest.importorskip("rsl_rl")
    code = main(["train", "--student", student, "--steps", "1000", "--teacher-param", "foo=1",
                 "--out", str(tmp_path / "run")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "unknown parameter(s) ['foo']" in err
    assert "whole number" not in err and not (tmp_path / "run").exists()


def test_reversed_bounds_are_named_as_written(tmp_path, capsys):
    code = main(["train", "--bounds", "stump_height=3,0", "--out", str(tmp_path / "run")])
    assert code == 2 and not (tmp_path / "run").exists()
    assert "bounds of 'stump_height'=[3.0, 0.0]; valid: min <= max" in capsys.readouterr().err
