"""The toy environment, the teacher runner, the sampling GIFs, `acl3d toy` and the bench script."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest

from acl3d.cli import main
from acl3d.teachers import make
from acl3d.teachers.plots import SamplingRecorder, render_frame, write_gif
from acl3d.toy import ToyEnv, run_teacher

ROOT = Path(__file__).resolve().parents[1]


def test_competence_spreads_from_the_origin_corner():
    env = ToyEnv(nb_dims=2, nb_cubes=10)
    assert env.episode([0.55, 0.55]) == 0.0  # locked: no mastered previous neighbour
    rewards = [env.episode([0.05, 0.05]) for _ in range(80)]
    assert rewards[0] == 0.01 and rewards[-1] == 0.80
    assert env.score() == 1.0  # one cube of 100 is above 75
    assert env.episode([0.15, 0.05]) == 0.01  # (1, 0) unlocked by (0, 0)
    assert env.episode([0.15, 0.15]) == 0.01  # diagonal neighbour counts too
    assert env.episode([0.25, 0.05]) == 0.0  # (2, 0) still locked
    assert env.episode([1.0, 1.0]) == 0.0  # the upper bound belongs to the last cube


def test_toy_dimensions_noise_and_input_checks():
    env = ToyEnv(nb_dims=3, nb_cubes=4, nb_irrelevant_dims=2)
    space = env.task_space()
    assert space.dim == 5 and np.all(space.low == 0) and np.all(space.high == 1)
    assert env.episode([0.1, 0.1, 0.1, 0.9, 0.3]) == env.episode([0.1, 0.1, 0.1, 0.2, 0.7]) - 0.01
    with pytest.raises(ValueError, match="length 5"):
        env.episode([0.1, 0.1, 0.1])
    with pytest.raises(ValueError, match="nb_cubes"):
        ToyEnv(nb_cubes=0)
    a = [ToyEnv(noise=0.1, seed=7).episode([0.0, 0.0]) for _ in range(2)]
    assert a[0] == a[1] and a[0] != 0.01
    assert env.competence_map().shape == (4, 4)


def test_mostly_unfeasible_variant_learns_only_inside_the_learnable_box():
    env = ToyEnv(nb_dims=3, nb_cubes=4, space_ratio=[2.0, 2.0, 3.0])
    space = env.task_space()
    assert list(space.high) == [2.0, 2.0, 3.0] and env.competence.shape == (4, 4, 4)
    assert env.episode([1.5, 0.0, 0.0]) == 0.0 and env.competence.sum() == 0
    assert env.episode([0.1, 0.1, 0.1]) == 0.01 and env.episode([1.0, 1.0, 1.0]) == 0.0
    assert not env.learnable([0.5, 0.5, 1.01]) and env.learnable([0.5, 0.5, 1.0])
    for bad in (0.5, "3", [2.0, 2.0], True):
        with pytest.raises(ValueError, match="space_ratio"):
            ToyEnv(nb_dims=3, space_ratio=bad)


def test_value_proxy_tracks_returns_and_reaches_value_teachers():
    env = ToyEnv(seed=0, space_ratio=2.0)
    seen = []
    teacher = make("robust-plr", env.task_space(), seed=0, buffer_size=50)
    run_teacher(teacher, env, 200, observer=lambda i, t, r: seen.append(r))
    critic = teacher.value_estimator
    assert critic([[1.5, 1.5]])[0] == 0.0  # unlearnable: no value
    assert 0.0 < critic([[0.05, 0.05]])[0] <= env.competence[0, 0] / 100
    assert len(teacher.bk["scores"]) == 200 and max(teacher.bk["scores"]) > 0


def test_run_teacher_maps_tasks_for_the_env():
    env = ToyEnv(seed=0)
    teacher = make("random", env.task_space(), seed=0)
    run_teacher(teacher, env, 50, to_env=lambda t: np.zeros(2))
    assert env.competence[0, 0] == 50  # every episode played the origin cube


def test_run_teacher_scores_and_cpu_accounting():
    env = ToyEnv(seed=0)
    teacher = make("random", env.task_space(), seed=0)
    seen = []
    run = run_teacher(teacher, env, 2500, score_every=1000, observer=lambda i, t, r: seen.append(i))
    assert run.episodes == [1000, 2000] and len(run.scores) == 2
    assert seen == list(range(2500)) and teacher.nb_episodes == 2500
    assert run.teacher_cpu_s > 0 and run.cpu_per_1000 == pytest.approx(
        1000 * run.teacher_cpu_s / 2500
    )
    with pytest.raises(ValueError, match="dimension"):
        run_teacher(make("random", {"x": [0, 1]}, seed=0), env, 10)


def test_toy_cli_prints_scores_and_writes_a_gif(tmp_path, capsys):
    gif = tmp_path / "riac.gif"
    code = main(
        [
            "toy",
            "--teacher",
            "riac",
            "--episodes",
            "600",
            "--seed",
            "0",
            "--score-every",
            "300",
            "--gif",
            str(gif),
            "--gif-every",
            "200",
            "--teacher-param",
            "max_region_size=40",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "episode     300" in out and "% mastered cubes" in out
    frames = imageio.mimread(gif)
    assert len(frames) == 3 and frames[0].ndim == 3


@pytest.mark.parametrize("teacher", ["accel", "terrain-levels"])
def test_toy_cli_unfeasible_space_with_ued_teachers(tmp_path, capsys, teacher):
    gif = tmp_path / "t.gif"
    argv = ["toy", "--teacher", teacher, "--episodes", "400", "--space-ratio", "3"]
    assert main([*argv, "--score-every", "200", "--gif", str(gif), "--gif-every", "200"]) == 0
    assert "% mastered cubes after 400 episodes" in capsys.readouterr().out
    assert len(imageio.mimread(gif)) == 2


def test_toy_cli_rejects_bad_parameters(capsys):
    assert (
        main(["toy", "--teacher", "alp-gmm", "--episodes", "10", "--teacher-param", "bogus=1"]) == 2
    )
    assert "bogus" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--episodes", "-1", "--episodes=-1; valid: an integer >= 0"),
        ("--seed", "-1", "--seed=-1; valid: an integer in [0, 2147483647]"),
        ("--nb-dims", "0", "--nb-dims=0; valid: an integer >= 1"),
        ("--gif-every", "0", "--gif-every=0; valid: an integer >= 1"),
        ("--gif", "sampling.txt", "--gif='sampling.txt'; valid: a file path ending in .gif"),
    ],
)
def test_toy_cli_names_a_bad_option_and_its_range_before_any_episode(
    tmp_path, capsys, monkeypatch, option, value, message
):
    monkeypatch.chdir(tmp_path)
    played = []
    monkeypatch.setattr("acl3d.cli.toy.run_teacher", lambda *a, **k: played.append(a))
    assert main(["toy", "--episodes", "10", option, value]) == 2
    assert capsys.readouterr().err.strip() == f"acl3d toy: error: {message}"
    assert not played and not list(tmp_path.iterdir())


def test_toy_cli_without_the_gif_packages_says_so_before_any_episode(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio", None)  # the core install, without [train]
    played = []
    monkeypatch.setattr("acl3d.cli.toy.run_teacher", lambda *a, **k: played.append(a))
    assert main(["toy", "--episodes", "10", "--gif", str(tmp_path / "x.gif")]) == 1
    err = capsys.readouterr().err
    assert "acl3d toy --gif needs" in err and 'pip install "acl3d[train]"' in err
    assert not played and not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "state",
    [
        None,
        {
            "kind": "gmm",
            "means": np.array([[0.2, 0.3], [0.7, 0.6]]),
            "covariances": np.array([np.eye(2) * 0.01, np.diag([0.02, 0.0])]),
            "weights": np.array([0.5, 0.0]),
        },
        {
            "kind": "boxes",
            "boxes": [(np.zeros(2), np.ones(2), 0.0), (np.zeros(2), np.array([0.5, 1.0]), 0.3)],
        },
        {"kind": "box", "low": np.array([0.1, 0.1]), "high": np.array([0.4, 0.3])},
        {
            "kind": "gaussian",
            "mean": np.array([0.5, 0.5]),
            "covariance": np.array([[0.02, 0.01], [0.01, 0.03]]),
        },
        {"kind": "lesson", "index": 1, "tasks": np.array([[0.1, 0.1], [0.5, 0.5], [0.9, 0.9]])},
    ],
    ids=["scatter", "gmm", "boxes", "box", "gaussian", "lesson"],
)
def test_every_plot_kind_renders(state):
    """Each kind draws itself: the frame differs from the same frame without the state (and the
    plain scatter from a frame without tasks), at the same size."""
    frame = {
        "episode": 10,
        "state": state,
        "tasks": np.random.default_rng(0).random((20, 2)),
        "values": np.linspace(0, 1, 20),
        "background": np.zeros((10, 10)),
    }
    image = render_frame(frame, [0, 0], [1, 1])
    assert image.dtype == np.uint8 and image.ndim == 3
    without = (
        {**frame, "state": None} if state is not None else {**frame, "tasks": np.zeros((0, 2))}
    )
    if state is None:
        without["values"] = np.zeros(0)
    other = render_frame(without, [0, 0], [1, 1])
    assert other.shape == image.shape
    changed = np.any(other != image, axis=2)
    assert changed.sum() > 200, f"only {changed.sum()} pixels show the {state and state['kind']}"


def test_gif_of_a_one_dimensional_teacher(tmp_path):
    teacher = make("adr", {"x": [0.0, 1.0]}, seed=0, min_reward_thr=0.0, max_reward_thr=0.5)
    recorder = SamplingRecorder(teacher, every=20)
    for i in range(60):
        task = teacher.sample_task()
        teacher.episodic_update(task, 1.0)
        recorder(i, task, 1.0)
    path = write_gif(recorder.frames, tmp_path / "adr.gif", [0.0], [1.0], ["x"])
    assert len(imageio.mimread(path)) == 3
    with pytest.raises(ValueError, match="no frames"):
        write_gif([], tmp_path / "none.gif", [0.0], [1.0])


def test_bench_script_quick_run(capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "scripts"))  # as when the script runs from a shell
    monkeypatch.setattr(
        sys,
        "argv",
        [
            "bench_teachers.py",
            "--reference",
            "--seeds",
            "2",
            "--episodes",
            "1000",
            "--teachers",
            "random,riac",
            "--preset",
            "teachdeeprl",
            "--variants",
            "plain,unfeasible",
        ],
    )
    with pytest.raises(SystemExit) as exit_info:
        runpy.run_path(str(ROOT / "scripts" / "bench_teachers.py"), run_name="__main__")
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert "| plain | riac | teachdeeprl |" in out and "| plain | random | teachdeeprl |" in out
    assert "| unfeasible | riac | teachdeeprl |" in out
    # the original RIAC ran on the same variants and seeds: its score, diff and p-value cells
    riac_row = next(line for line in out.splitlines() if line.startswith("| plain | riac |"))
    cells = [c.strip() for c in riac_row.strip("|").split("|")]
    assert "±" in cells[-5] and cells[-4].startswith(("+", "-"))
    random_row = next(line for line in out.splitlines() if line.startswith("| plain | random |"))
    assert random_row.rstrip().endswith("| – | – | – | – | – |")  # no original to compare with


@pytest.mark.parametrize("harness", ["edge-cubes", "unit-space", "score-ge75"])
def test_bench_script_harness_variants(capsys, monkeypatch, harness):
    """The unfeasible toy played as other harnesses might have: each runs acl3d's teacher and
    the original on the same seeds, and the option refuses variants it does not apply to."""
    monkeypatch.syspath_prepend(str(ROOT / "scripts"))
    argv = ["bench_teachers.py", "--seeds", "1", "--episodes", "300", "--teachers", "riac"]
    argv += ["--preset", "teachdeeprl", "--reference", "--harness", harness]
    monkeypatch.setattr(sys, "argv", [*argv, "--variants", "unfeasible"])
    with pytest.raises(SystemExit) as exit_info:
        runpy.run_path(str(ROOT / "scripts" / "bench_teachers.py"), run_name="__main__")
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert f"harness {harness}" in out and "| unfeasible | riac | teachdeeprl |" in out
    monkeypatch.setattr(sys, "argv", [*argv, "--variants", "plain"])
    with pytest.raises(SystemExit) as exit_info:
        runpy.run_path(str(ROOT / "scripts" / "bench_teachers.py"), run_name="__main__")
    assert exit_info.value.code == 2
    assert "--harness" in capsys.readouterr().err


def test_harness_toys_differ_from_the_toy_where_they_should():
    """edge-cubes learns out-of-range tasks in the clipped edge cube; score-ge75 counts 75."""
    bench = runpy.run_path(str(ROOT / "scripts" / "bench_teachers.py"))
    edge, _, space = bench["make_env"]("unfeasible", 0, 2, 3.0, "edge-cubes")
    assert space.high.tolist() == [3.0, 3.0]
    assert edge.episode([0.05, 2.5]) == 0.0  # cube (0, 9): locked
    edge.competence[0, 8] = 75  # unlock (0, 9) from below
    assert edge.episode([0.05, 2.5]) == 0.01 and edge.competence[0, 9] == 1
    env, to_env, unit = bench["make_env"]("unfeasible", 0, 2, 3.0, "unit-space")
    assert unit.high.tolist() == [1.0, 1.0] and np.allclose(to_env([0.5, 0.1]), [1.5, 0.3])
    ge, _, _ = bench["make_env"]("unfeasible", 0, 2, 3.0, "score-ge75")
    ge.competence[0, 0] = 75
    assert ge.score() == 1.0 and ToyEnv(space_ratio=3.0).score() == 0.0
