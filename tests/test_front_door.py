"""What a new user meets first: the defaults, the messages of short runs, the help texts, and the
commands that used to fail or mislead silently (evaluate without normalisation statistics,
analyze on degenerate data, check_env on a headless machine, curriculum animations' scales)."""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import shutil

import gymnasium as gym
import numpy as np
import pytest
import yaml
from gymnasium.utils.env_checker import check_env
from test_training_run import FAST

from acl3d.cli import build_parser, main
from acl3d.cli.train import default_run_dir, options_from_args
from acl3d.envs import ENV_NAMES
from acl3d.teachers import TEACHERS
from acl3d.teachers.plots import render_frame
from acl3d.training.config import BENCHMARK, TrainConfig


def _train_options(*argv: str) -> dict:
    return options_from_args(build_parser().parse_args(["train", *argv]))


def test_the_defaults_are_the_quickstart_and_the_benchmark_is_one_flag_away():
    config = TrainConfig.from_dict(_train_options())
    assert (config.teacher, config.student, config.preset) == ("alp-gmm", "rsl-ppo", "fast")
    assert (config.steps, config.effective_n_envs) == (2_000_000, 64)
    assert (config.expert_knowledge, config.nb_test_episodes) == ("high", 25)
    sac = TrainConfig.from_dict(_train_options("--benchmark", "sac"))
    assert {k: getattr(sac, k) for k in BENCHMARK["sac"]} == BENCHMARK["sac"]
    assert (sac.preset, sac.steps, sac.nb_test_episodes) == ("benchmark", 20_000_000, 100)
    assert sac.expert_knowledge == "low" and not sac.eval_stochastic
    ppo = TrainConfig.from_dict(_train_options("--benchmark", "ppo", "--steps", "1e6"))
    assert (ppo.student, ppo.preset, ppo.steps, ppo.eval_stochastic) == (
        "ppo",
        "benchmark",
        10**6,
        True,
    )


def test_a_run_without_out_gets_a_new_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    first = default_run_dir({})
    assert first == "runs/alp-gmm-rsl-ppo-seed0"
    (tmp_path / first).mkdir(parents=True)
    assert default_run_dir({}) == "runs/alp-gmm-rsl-ppo-seed0-2"
    assert default_run_dir({"teacher": "riac", "seed": 3}) == "runs/riac-rsl-ppo-seed3"
    assert default_run_dir({"student": "sac"}) == "runs/alp-gmm-sac-seed0"


def _commands(parser: argparse.ArgumentParser, name: str = "acl3d"):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub, subparser in action.choices.items():
                yield from _commands(subparser, f"{name} {sub}")
    yield name, parser


def test_every_option_of_every_command_says_what_it_does():
    missing = [
        f"{name} {action.option_strings or action.dest}"
        for name, parser in _commands(build_parser())
        for action in parser._actions
        if not isinstance(action, argparse._SubParsersAction)
        if not action.help or "..." in action.help
    ]
    assert not missing, missing


def test_train_help_lists_every_environment_and_teacher(capsys):
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert all(name in text for name in (*ENV_NAMES, *TEACHERS))


def test_toy_takes_teacher_param_like_train():
    parse = build_parser().parse_args
    assert parse(["toy", "--teacher-param", "fit_rate=50"]).param == [("fit_rate", 50)]
    with pytest.raises(SystemExit):  # the old --param spelling is gone
        parse(["toy", "--param", "fit_rate=50"])


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """A run shorter than two evaluation intervals, with a test-set size the grid cannot keep."""
    out = tmp_path_factory.mktemp("front") / "run"
    stdout, stderr = io.StringIO(), io.StringIO()
    loud = [arg for arg in FAST if arg != "--quiet"]
    argv = ["train", *loud, "--steps", "256", "--n-envs", "2", "--nb-test-episodes", "8",
            "--no-tensorboard", "--out", str(out)]  # fmt: skip
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        assert main(argv) == 0
    return out, stdout.getvalue(), stderr.getvalue()


def test_a_test_set_smaller_than_asked_is_announced_and_recorded(short_run):
    out, _, stderr = short_run
    assert "nb_test_episodes=8" in stderr and "4 test tasks" in stderr
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert config["resolved"]["nb_test_episodes"] == 4


def test_a_run_with_only_its_final_evaluation_says_so(short_run):
    _, stdout, stderr = short_run
    assert "one evaluation, at the end of training" in stderr
    assert "evaluating on 4 test tasks" in stdout  # a message while the progress bar waits


def test_tensorboard_logging_can_be_switched_off(short_run):
    out, _, _ = short_run
    assert (out / "final_model.zip").exists() and (out / "evals.csv").exists()
    assert not list(out.rglob("events.out.tfevents*"))


def test_evaluate_refuses_a_ppo_model_without_its_normalisation(short_run, tmp_path, capsys):
    out, _, _ = short_run
    model = tmp_path / "model.zip"
    shutil.copy(out / "final_model.zip", model)
    argv = ["evaluate", str(model), "--env", "stump-tracks", "--nb-test-episodes", "4",
            "--n-envs", "1"]  # fmt: skip
    assert main(argv) == 2
    assert "--raw-observations" in capsys.readouterr().err
    assert main([*argv, "--raw-observations"]) == 0
    captured = capsys.readouterr()
    assert "warning" in captured.err and "4 test episodes" in captured.out


def _write_run(root, name, teacher, seed, mastered, mean_return):
    run = root / "runs" / name
    run.mkdir(parents=True)
    config = {"env": "stump-tracks", "teacher": teacher, "seed": seed}
    (run / "config.yaml").write_text(yaml.safe_dump({"config": config}))
    (run / "status.json").write_text(json.dumps({"status": "finished"}))
    with (run / "evals.csv").open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["step", "episodes", "mastered_pct", "mean_return"])
        writer.writerow([1000, 10, mastered, mean_return])


def test_analyze_warns_on_degenerate_data_and_names_the_metric_to_try(tmp_path, capsys):
    _write_run(tmp_path, "random__s0", "random", 0, 0.0, -100.0)
    _write_run(tmp_path, "alp-gmm__s0", "alp-gmm", 0, 0.0, -80.0)
    assert main(["analyze", str(tmp_path), "--reps", "100"]) == 0
    err = capsys.readouterr().err
    assert "final mastered_pct is 0" in err and "--metric mean_return" in err
    assert "single run" in err
    assert "**Warning**" in (tmp_path / "report" / "report.md").read_text()


def test_check_env_passes_headless_without_the_viewer_and_says_what_the_viewer_needs(
    monkeypatch,
):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    env = gym.make("acl3d/StumpTracks-v0")
    check_env(env.unwrapped, skip_render_check=True)
    with pytest.raises(RuntimeError, match="DISPLAY"):
        check_env(env.unwrapped)  # its render check opens MuJoCo's viewer


def _colour_bar_columns(image: np.ndarray) -> int:
    """Columns right of the plot holding saturated colours (a colour bar's)."""
    right = image[:, int(image.shape[1] * 0.8) :].astype(int)
    saturated = (right.max(axis=2) - right.min(axis=2)) > 60
    return int(saturated.any(axis=0).sum())


def test_curriculum_frames_carry_a_fixed_colour_scale():
    tasks = np.array([[1.0, 2.0], [2.0, 4.0]])
    low, high = [0.0, 0.0], [3.0, 6.0]
    frame = {"episode": 2, "tasks": tasks, "values": np.array([0.0, 100.0]),
             "value_range": (-100.0, 300.0), "value_label": "episode return"}  # fmt: skip
    image = render_frame(frame, low, high)
    assert _colour_bar_columns(image) > 5
    # Another value for the second task recolours that marker only: the scale, its ticks and
    # the first task's colour stay (a per-frame scale would change all three).
    other = render_frame({**frame, "values": np.array([0.0, -100.0])}, low, high)
    assert 0 < np.any(image != other, axis=2).sum() < 60
