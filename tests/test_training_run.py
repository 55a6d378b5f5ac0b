"""End-to-end training on the real Stump Tracks: run directory, resume, evaluate, report, errors."""

from __future__ import annotations

import json
import re
import shutil

import gymnasium as gym
import numpy as np
import pytest
import yaml
from gl_support import require_offscreen_gl

from acl3d import results
from acl3d.cli import main
from acl3d.run_format.tables import read_csv
from acl3d.teachers.state_files import load_state
from acl3d.training import TrainConfig, train
from acl3d.training.curriculum import WorkerError
from acl3d.training.run_dir import RunDir

# Short episodes and small PPO rollouts keep a real training run to a few seconds.
FAST = [
    "--env", "stump-tracks", "--student", "ppo", "--preset", "fast", "--teacher", "random",
    "--student-param", "n_steps=128", "--student-param", "batch_size=128",
    "--env-kwarg", "max_episode_steps=60", "--nb-test-episodes", "4", "--no-progress", "--quiet",
]  # fmt: skip


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "ppo"
    rc = main(
        [
            "train",
            *FAST,
            "--steps",
            "1024",
            "--n-envs",
            "2",
            "--eval-every",
            "512",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    return out


def test_train_writes_a_complete_run_directory(trained_run):
    run = RunDir(trained_run)
    doc = yaml.safe_load(run.config_yaml.read_text())
    assert doc["config"]["teacher"] == "random" and doc["config"]["n_envs"] == 2
    assert doc["environment"]["packages"]["stable-baselines3"]
    assert doc["student_hyperparameters"]["n_steps"] == 128
    assert json.loads((trained_run / "status.json").read_text())["status"] == "finished"
    evals = read_csv(run.evals_csv)
    assert evals["step"] == [512.0, 1024.0]
    assert all(0 <= m <= 100 for m in evals["mastered_pct"])
    assert len(read_csv(run.evals_tasks_csv)["step"]) == 2 * 4
    episodes = read_csv(run.episodes_csv)
    assert {"stump_height", "obstacle_spacing", "return", "length"} <= set(episodes)
    assert max(episodes["length"]) <= 60
    dump = load_state(run.teacher_prefix)
    assert len(dump["train_returns"]) == len(episodes["step"])  # every episode reached the teacher
    np.testing.assert_allclose(dump["train_returns"], episodes["return"], rtol=1e-5, atol=1e-4)
    assert dump["test_tasks"].shape == (4, 2)
    assert len(dump["test_returns"]) == 8
    assert (trained_run / "final_model.zip").exists()
    assert (trained_run / "final_model_vecnormalize.npz").exists()
    latest = run.latest_checkpoint()
    for name in (
        "model.zip",
        "model_vecnormalize.json",
        "controller.json",
        "rng.npz",
        "progress.json",
    ):
        assert (latest / name).exists(), name
    events = b"".join(p.read_bytes() for p in run.tb.rglob("events.out.tfevents*"))
    for tag in (
        b"curriculum/mean_task/stump_height",
        b"eval/mastered_pct",
        b"curriculum/episode_return",
    ):
        assert tag in events


def test_resume_continues_model_teacher_and_logs(trained_run, tmp_path):
    run_dir = tmp_path / "resumed"
    shutil.copytree(trained_run, run_dir)
    checkpoint = RunDir(run_dir).latest_checkpoint()
    saved = load_state(checkpoint / "controller")
    n_sampled = len(saved["records"]["sampled_tasks"])

    rc = main(["train", "--resume", str(run_dir), "--steps", "2048", "--no-progress", "--quiet"])
    assert rc == 0
    evals = read_csv(RunDir(run_dir).evals_csv)
    assert evals["step"] == [512.0, 1024.0, 1536.0, 2048.0]
    dump = load_state(RunDir(run_dir).teacher_prefix)
    # The records before the checkpoint are kept, and the teacher's RNG continues exactly:
    # the first task sampled after resuming is the one a restored controller samples (the
    # queued tasks of the envs are restored, not re-sampled; tests/test_resume.py compares
    # whole runs).
    np.testing.assert_array_equal(
        dump["sampled_tasks"][:n_sampled], saved["records"]["sampled_tasks"]
    )
    from acl3d.teachers.controller import TeacherController

    fresh = TeacherController("random", dump_space(dump), 0)
    fresh.load_state_dict(saved)
    np.testing.assert_array_equal(dump["sampled_tasks"][n_sampled], fresh.sample_task())
    assert len(list(RunDir(run_dir).tb.glob("train_*"))) == 1  # TensorBoard continues its run


def dump_space(dump):
    from acl3d.task_space import TaskSpace

    return TaskSpace.from_bounds(dump["bounds"])


def test_resume_refuses_changed_settings(trained_run):
    with pytest.raises(ValueError, match="cannot change.*teacher"):
        train(resume=trained_run, teacher="alp-gmm")


def test_evaluate_cli_on_run_dir(trained_run, tmp_path, capsys):
    out = tmp_path / "eval.csv"
    rc = main(["evaluate", str(trained_run), "--n-envs", "2", "--out", str(out)])
    assert rc == 0
    assert "% mastered" in capsys.readouterr().out
    rows = read_csv(out)
    assert {"stump_height", "obstacle_spacing"} <= set(rows)
    assert len(rows["return"]) == 4 and all(length <= 60 for length in rows["length"])
    # a size draws the run's kind of test set (the default grid) at that size, not ignored
    assert main(["evaluate", str(trained_run), "--nb-test-episodes", "9", "--out", str(out)]) == 0
    assert "on test set default (9 tasks x 1)" in capsys.readouterr().out
    assert len(read_csv(out)["return"]) == 9
    tasks = tmp_path / "tasks.json"
    tasks.write_text(json.dumps([{"stump_height": 0.5, "obstacle_spacing": 3.0}]))
    argv = ["evaluate", str(trained_run), "--test-set", str(tasks), "--nb-test-episodes", "9"]
    assert main(argv) == 2  # a file holds its own tasks: a size for it is refused
    assert "--nb-test-episodes=9; valid: with a test set drawn at a size" in capsys.readouterr().err
    # on another env the run's test tasks (another task space) give way to that env's default
    assert main(["evaluate", str(trained_run), "--env", "hexagon-tracks", "--out", str(out)]) == 0
    assert "on test set default" in capsys.readouterr().out
    assert "poly_shape[0]" in read_csv(out)


def test_evaluate_reproduces_the_runs_last_evaluation(trained_run, tmp_path, capsys):
    """By default: the run's test set, evaluation seed, eval envs and action mode."""
    own = read_csv(RunDir(trained_run).evals_tasks_csv)
    last = [i for i, step in enumerate(own["step"]) if step == 1024]
    out = tmp_path / "eval.csv"
    assert main(["evaluate", str(trained_run), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    seed = TrainConfig().seed + 7919
    assert f"step 1024) on the run's test set (4 tasks x 1), seed {seed}, 2 envs" in printed
    assert "deterministic actions" in printed and "the run's own evaluation at step 1024" in printed
    rows = read_csv(out)
    assert rows["return"] == [own["return"][i] for i in last]
    assert rows["length"] == [own["length"][i] for i in last]
    assert main(["evaluate", str(trained_run), "--seed", "5", "--out", str(out)]) == 0
    assert "seed 5," in capsys.readouterr().out
    assert read_csv(out)["return"] != [own["return"][i] for i in last]


def test_evaluate_a_runs_model_zip_with_the_runs_settings(trained_run, tmp_path, capsys):
    """RUN/final_model.zip and a checkpoint's model.zip need no --env: the run's own settings."""
    own = read_csv(RunDir(trained_run).evals_tasks_csv)
    last = [own["return"][i] for i, step in enumerate(own["step"]) if step == 1024]
    latest = (trained_run / "checkpoints" / "LATEST").read_text().strip()
    out = tmp_path / "eval.csv"
    seed = TrainConfig().seed + 7919
    for model in (
        trained_run / "final_model.zip",
        trained_run / "checkpoints" / latest / "model.zip",
    ):
        assert main(["evaluate", str(model), "--out", str(out)]) == 0
        printed = capsys.readouterr().out
        assert f"step 1024) on the run's test set (4 tasks x 1), seed {seed}, 2 envs" in printed
        assert read_csv(out)["return"] == last


def test_report_writes_plots_and_video(trained_run, tmp_path):
    require_offscreen_gl()
    out = tmp_path / "report"
    rc = main(
        ["report", str(trained_run), "--out", str(out), "--video-tasks", "2", "--video-steps", "30"]
    )
    assert rc == 0
    for name in ("mastered.png", "returns.png", "curriculum.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    import imageio.v2 as imageio

    with imageio.get_reader(out / "final.mp4") as reader:
        frames = sum(1 for _ in reader)
    assert frames >= 2 * 15


def test_sac_with_self_paced_teacher_gets_values_and_steps(tmp_path):
    """SPDL needs step rewards, initial states and the SAC critics; the run must feed all three."""
    result = train(
        TrainConfig(
            env="stump-tracks",
            teacher="self-paced",
            student="sac",
            preset="fast",
            steps=600,
            n_envs=1,
            out=str(tmp_path / "sac"),
            env_kwargs={"max_episode_steps": 40},
            test_set="uniform",
            nb_test_episodes=1,
            eval_every=600,
            teacher_params={"update_frequency": 200, "update_offset": 0},
            student_params={"learning_starts": 100},
            reset_student_every=300,
            progress_bar=False,
            verbose=0,
        )
    )
    assert result.steps == 600
    dump = load_state(RunDir(result.run_dir).teacher_prefix)
    assert len(dump["train_returns"]) > 0
    assert len(dump["teacher_bk"]["steps"]) >= 2  # SPDL updated its distribution
    events = b"".join(p.read_bytes() for p in RunDir(result.run_dir).tb.rglob("events.out*"))
    assert b"curriculum/student_resets" in events
    assert b"curriculum/teacher/kl" in events  # teacher-specific scalars reach TensorBoard


class ExplodingReset(gym.Wrapper):
    """A real track whose 6th reset raises, to check what a crashed run leaves behind."""

    def __init__(self, env):
        super().__init__(env)
        self.resets = 0

    def reset(self, **kwargs):
        self.resets += 1
        if self.resets == 6:
            raise FloatingPointError("simulation diverged (on purpose)")
        return self.env.reset(**kwargs)


def make_exploding(**kwargs):
    from acl3d.envs import make

    return ExplodingReset(make("stump-tracks", **kwargs))


gym.register("acl3dtest/Exploding-v0", entry_point=make_exploding)


def test_crashed_worker_stops_the_run_and_keeps_checkpoints(tmp_path):
    out = tmp_path / "crash"
    with pytest.raises(WorkerError, match="(?s)FloatingPointError: simulation diverged"):
        train(
            env="acl3dtest/Exploding-v0",
            student="ppo",
            preset="fast",
            steps=100_000,
            env_kwargs={"max_episode_steps": 30},
            student_params={"n_steps": 64, "batch_size": 64},
            eval_every=64,
            test_set="uniform",
            nb_test_episodes=1,
            vec_env="dummy",
            out=str(out),
            progress_bar=False,
            verbose=0,
        )
    status = json.loads((out / "status.json").read_text())
    assert status["status"] == "crashed" and "simulation diverged" in status["traceback"]
    model = RunDir(out).best_model()  # what was saved so far stays usable
    assert model.parent.name == status["latest_checkpoint"]
    assert main(["evaluate", str(out), "--n-envs", "1", "--env", "stump-tracks"]) == 0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--env", "nope"], "valid: stump-tracks"),
        (["--body", "nope"], "valid bodies: classic_bipedal"),
        (["--teacher", "nope"], "valid teachers: random"),
        (["--student", "nope"], "valid students: sac, ppo"),
        (["--preset", "nope"], "valid presets: benchmark, fast"),
        (["--student", "ppo", "--buffer-size", "1000"], "sac student only"),
        (["--student-param", "batch_size=100000"], "batch_size"),
        (["--bounds", "stump_heigth=0,9"], "valid: \\['stump_height'"),
        (["--reset-student-every", "5000"], "never reset"),
    ],
)
def test_bad_input_fails_before_training(args, message, tmp_path, capsys):
    out = tmp_path / "bad"
    base = ["train", "--student", "ppo", "--preset", "fast", "--steps", "1000", "--out", str(out)]
    rc = main([*base, *args])
    assert rc == 2
    err = capsys.readouterr().err
    assert re.search(message, err), err
    assert not out.exists()


def test_config_file_holds_options_and_cli_overrides_it(tmp_path):
    from acl3d.cli import build_parser
    from acl3d.cli.train import options_from_args

    cfg = tmp_path / "run.yaml"
    cfg.write_text("teacher: alp-gmm\nsteps: 2e6\nn-envs: 4\nteacher_params: {nb_em_init: 2}\n")
    toml = tmp_path / "run.toml"
    toml.write_text('teacher = "riac"\nsteps = 1000\n')
    args = build_parser().parse_args(
        ["train", "--config", str(cfg), "--n-envs", "2", "--teacher-param", "fit_rate=100",
         "--bounds", "stump_height=0,9", "--steps", "3e5"]
    )  # fmt: skip
    options = options_from_args(args)
    assert options["teacher"] == "alp-gmm" and options["n_envs"] == 2 and options["steps"] == 300000
    assert options["teacher_params"] == {"nb_em_init": 2, "fit_rate": 100}
    assert options["bounds"] == {"stump_height": [0.0, 9.0]}
    assert (
        options_from_args(build_parser().parse_args(["train", "--config", str(cfg)]))["steps"]
        == 2_000_000
    )
    toml_args = build_parser().parse_args(["train", "--config", str(toml)])
    assert options_from_args(toml_args) == {"teacher": "riac", "steps": 1000}
    config = TrainConfig.from_dict({"steps": 2_000_000})
    assert config.effective_eval_every == 400_000  # TeachMyAgent's 500k, scaled to 5 evals
    assert TrainConfig.from_dict({"steps": 20_000_000}).effective_eval_every == 500_000
    assert TrainConfig.from_dict({"steps": 10_000}).effective_eval_every == 50_000  # final only


def test_config_takes_a_runs_config_yaml_as_its_recipe_without_its_folder(tmp_path):
    from acl3d.cli import build_parser
    from acl3d.cli.train import options_from_args

    shipped = results.path("stump-rsl") / "random__s0" / "config.yaml"
    recorded = yaml.safe_load(shipped.read_text())["config"]
    options = options_from_args(
        build_parser().parse_args(["train", "--config", str(shipped), "--seed", "3"])
    )
    assert options == {**recorded, "seed": 3}
    local = tmp_path / "config.yaml"  # a run directory's own records its folder
    local.write_text(yaml.safe_dump({"config": {**recorded, "out": "runs/x"}, "environment": {}}))
    options = options_from_args(build_parser().parse_args(["train", "--config", str(local)]))
    assert "out" not in options and options["student_params"] == recorded["student_params"]


@pytest.mark.parametrize(
    ("bad", "name"),
    [
        ({"steps": "1000"}, "steps"),
        ({"steps": 2.5}, "steps"),
        ({"steps": True}, "steps"),
        ({"seed": True}, "seed"),
        ({"n_envs": 0}, "n_envs"),
        ({"shuffle_dimensions": "False"}, "shuffle_dimensions"),
        ({"eval_stochastic": 1}, "eval_stochastic"),
        ({"verbose": 5}, "verbose"),
        ({"bounds": {"stump_height": ["0", 3]}}, "bounds"),
        ({"bounds": {"stump_height": [0, 1j]}}, "bounds"),
        ({"n_envs": 2, "envs_per_worker": 3}, "envs_per_worker"),
        ({"teacher_params": [1]}, "teacher_params"),
        ({"device": 0}, "device"),
        ({"student": "sb3:DQN"}, "student='sb3:DQN'; DQN does not support"),  # Discrete only
    ],
)
def test_config_is_strict(bad, name, tmp_path):
    """No silent coercion: a string, bool or complex where a number or flag is meant fails
    with the parameter's name, before the run directory exists."""
    out = tmp_path / "strict"
    with pytest.raises(ValueError, match=name):
        train(out=str(out), progress_bar=False, **bad)
    assert not out.exists()
    assert TrainConfig(steps=2e6).steps == 2_000_000  # a count written 2e6 is fine


def test_switches_set_their_fields_and_off_switches_clear_theirs():
    from acl3d.cli import build_parser
    from acl3d.cli.train import options_from_args

    on = ["--eval-stochastic", "--shuffle-dimensions", "--scale-reward"]
    off = ["--no-progress", "--no-tensorboard", "--no-replay-buffer-save", "--quiet"]
    options = options_from_args(build_parser().parse_args(["train", *on, *off]))
    assert options["eval_stochastic"] and options["shuffle_dimensions"] and options["scale_reward"]
    assert not any(options[k] for k in ("progress_bar", "tensorboard", "save_replay_buffer"))
    assert options["verbose"] == 0
