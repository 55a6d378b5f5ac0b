"""Curriculum animations of real run directories (`acl3d render --curriculum RUN`)."""

from __future__ import annotations

import imageio.v2 as imageio
import numpy as np
import pytest

from acl3d.cli import main
from acl3d.run_format.tables import read_csv
from acl3d.teachers import make
from acl3d.teachers.expert_knowledge import toy_teacher_params
from acl3d.teachers.state_files import load_state
from acl3d.toy import ToyEnv, run_teacher
from acl3d.training.curriculum_animation import curriculum_frames, teacher_states
from acl3d.training.run_dir import RunDir

# RIAC with small regions splits several times within a few thousand steps of short episodes.
RIAC_RUN = [
    "train", "--env", "stump-tracks", "--student", "ppo", "--preset", "fast", "--teacher", "riac",
    "--teacher-param", "max_region_size=15", "--student-param", "n_steps=256",
    "--student-param", "batch_size=256", "--env-kwarg", "max_episode_steps=20",
    "--steps", "1024", "--eval-every", "1024", "--nb-test-episodes", "4", "--no-progress",
    "--quiet",
]  # fmt: skip


@pytest.fixture(scope="module")
def riac_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "riac"
    assert main([*RIAC_RUN, "--out", str(out)]) == 0
    return out


def test_riac_regions_rebuilt_from_the_book_keeping_match_the_teacher(riac_run):
    run = RunDir(riac_run)
    dump = load_state(run.teacher_prefix)
    states = teacher_states(dump, np.asarray(read_csv(run.episodes_csv)["step"]))
    assert len(states) >= 2  # several splits: the test compares something
    teacher = load_state(run.latest_checkpoint() / "controller")["teacher"]["extra"]
    leaves = [i for i, c in enumerate(teacher["children"]) if c is None]
    expected = sorted((tuple(teacher["low"][i]), tuple(teacher["high"][i])) for i in leaves)
    rebuilt = sorted((tuple(lo), tuple(hi)) for lo, hi, _ in states[-1][1]["boxes"])
    np.testing.assert_allclose(rebuilt, expected)


def test_frames_cover_every_training_episode_once(riac_run):
    frames, facts = curriculum_frames(riac_run, frames=7)
    n_episodes = len(read_csv(RunDir(riac_run).episodes_csv)["step"])
    assert len(frames) == 7
    assert sum(len(f["tasks"]) for f in frames) == n_episodes
    assert frames[-1]["episode"] == n_episodes
    assert frames[0]["state"] is None and frames[-1]["state"]["kind"] == "boxes"
    assert facts["names"] == ["stump_height", "obstacle_spacing"] and facts["teacher"] == "riac"


def test_render_cli_writes_the_curriculum_animation(riac_run, tmp_path):
    out = tmp_path / "curriculum.gif"
    assert main(["render", "--curriculum", str(riac_run), "--frames", "5", "--out", str(out)]) == 0
    frames = imageio.mimread(out)
    assert len(frames) == 5 and len({f.shape for f in frames}) == 1
    assert not np.array_equal(frames[0], frames[-1])


def test_a_directory_that_is_not_a_run_is_refused(tmp_path, capsys):
    code = main(["render", "--curriculum", str(tmp_path), "--out", str(tmp_path / "x.gif")])
    assert code == 2 and "not a run directory" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("name", "params"),
    [
        ("alp-gmm", {"fit_rate": 50}),
        ("covar-gmm", {"fit_rate": 50}),
        ("adr", {}),
        ("riac", {"max_region_size": 30}),
        ("self-paced", {"update_offset": 100, "update_frequency": 100}),
    ],
)
def test_the_last_rebuilt_state_is_the_teachers_own(name, params):
    """Each teacher's book-keeping, replayed, ends at the state the teacher itself plots."""
    env = ToyEnv(seed=0)
    params = {**toy_teacher_params(name, env.curriculum_profile, env.task_space()), **params}
    teacher = make(name, env.task_space(), seed=0, **params)
    run_teacher(teacher, env, 400)
    dump = {"teacher": name, "teacher_bk": teacher.dump(), "low": [0, 0], "high": [1, 1]}
    states = teacher_states(dump, np.arange(1, 401))
    assert states, "no state history: nothing to compare"
    rebuilt, own = states[-1][1], teacher.plot_state()
    assert rebuilt["kind"] == own["kind"]
    if own["kind"] == "boxes":  # RIAC plots every region; the animation its leaves
        own_boxes = {(tuple(lo), tuple(hi)) for lo, hi, _ in own["boxes"]}
        assert {(tuple(lo), tuple(hi)) for lo, hi, _ in rebuilt["boxes"]} <= own_boxes
    keys = ("means", "covariances", "low", "high", "mean", "covariance")
    for key in keys + (("weights",) if name == "alp-gmm" else ()):
        if key in own:
            np.testing.assert_allclose(rebuilt[key], own[key], rtol=1e-6, atol=1e-9)
