"""Trained-policy playback, labels, comparison grids and PNG strips (acl3d.playback, `acl3d render`)."""

import re

import imageio.v2 as imageio
import numpy as np
import pytest
import torch
from gl_support import require_offscreen_gl
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from acl3d.cli import main
from acl3d.overlay import draw_label, wrap_line
from acl3d.playback import EpisodePlayer, record_grid, record_rollouts
from acl3d.training import checkpoint
from acl3d.training.evaluation import evaluate_saved_model
from acl3d.training.trained_policy import TrainedPolicy
from acl3d.training.workers import make_env

SHORT = {"max_episode_steps": 60}  # a time limit that keeps every test episode short
TASKS = np.array([[0.0, 6.0], [1.5, 3.0], [2.5, 1.0]], dtype=np.float32)


@pytest.fixture(autouse=True)
def _gl():
    require_offscreen_gl()


@pytest.fixture(scope="module")
def model_zip(tmp_path_factory):
    """An untrained PPO with large output weights (bang-bang actions that depend on every
    observation) and non-trivial VecNormalize statistics saved beside it."""
    path = tmp_path_factory.mktemp("model") / "model.zip"
    env = make_env("stump-tracks", "classic_bipedal", SHORT)
    model = PPO(
        "MlpPolicy",
        env,
        n_steps=64,
        batch_size=64,
        seed=0,
        device="cpu",
        policy_kwargs={"net_arch": [16, 16]},
    )
    with torch.no_grad():
        model.policy.action_net.weight.mul_(300.0)
    model.save(path)
    vecnorm = VecNormalize(DummyVecEnv([lambda: env]), norm_reward=False)
    rng = np.random.default_rng(1)
    vecnorm.obs_rms.mean = rng.normal(size=env.observation_space.shape)
    vecnorm.obs_rms.var = rng.uniform(0.2, 3.0, size=env.observation_space.shape)
    checkpoint.save_normalization(vecnorm, path)
    vecnorm.close()
    return path


def test_the_label_changes_only_its_corner():
    frame = np.full((120, 160, 3), 200, dtype=np.uint8)
    labelled = draw_label(frame.copy(), ["run (alp-gmm)", "stump_height=1.50", "step 12"])
    changed = np.argwhere((labelled != frame).any(axis=2))
    assert len(changed) > 200  # a dimmed box with text
    assert changed[:, 0].max() < 60 and changed[:, 1].max() < 130  # top-left only
    box = labelled[: changed[:, 0].max(), : changed[:, 1].max()]
    assert box.min() < 120 and box.max() > 240  # dimmed background, white text
    tiny = np.zeros((10, 10, 3), dtype=np.uint8)  # narrower than any word: each on its own line
    draw_label(tiny, ["step 12  return -3.0", "  "])
    assert wrap_line("step 12  return", 10, 1) == ["step", "12", "return"]


def test_playback_on_a_rendered_frame_labels_the_corner_only():
    # 320 px: wide enough for the task line unwrapped (narrower frames wrap it onto more rows)
    env = make_env("stump-tracks", "classic_bipedal", {"width": 320, "height": 120}, "rgb_array")
    player = EpisodePlayer(env, lambda obs: np.zeros(4, dtype=np.float32), "zero", overlay=True)
    player.reset(TASKS[1], seed=0)
    labelled = player.frame()
    plain = env.render()
    env.close()
    differs = (labelled != plain).any(axis=2)
    assert differs[:30, :100].mean() > 0.5 and not differs[60:, :].any()


def test_model_playback_reproduces_the_evaluation_returns(model_zip, tmp_path):
    evaluated = evaluate_saved_model(
        model_zip, "stump-tracks", "classic_bipedal", TASKS, env_kwargs=SHORT, n_envs=1, seed=11
    )
    env = make_env("stump-tracks", "classic_bipedal", dict(SHORT, width=96, height=64), "rgb_array")
    policy = TrainedPolicy(model_zip)
    assert policy.normalized
    played = record_rollouts(env, policy, tmp_path / "v.gif", TASKS, seed=11, progress=False)
    env.close()
    returns = np.array([s["return"] for s in played])
    assert [s["length"] for s in played] == evaluated.lengths.tolist()
    assert np.array_equal(returns, evaluated.returns)  # bit-identical
    assert len(set(returns.tolist())) == 3  # the episodes differ: a test that can fail


def test_a_model_for_another_body_is_refused(model_zip):
    env = make_env("stump-tracks", "spider", {})
    with pytest.raises(ValueError, match="observations of shape"):
        TrainedPolicy(model_zip).check_env(env)
    env.close()


def test_grid_and_strip_frame_sizes(tmp_path):
    players = [
        EpisodePlayer(
            make_env("stump-tracks", "classic_bipedal", {"width": 64, "height": 48}, "rgb_array"),
            lambda obs, v=v: np.full(4, v, dtype=np.float32),
            f"cell {v}",
        )
        for v in (-0.5, 0.0, 0.5)
    ]
    gif = tmp_path / "grid.gif"
    runs = record_grid(players, gif, TASKS[:2], max_steps=12, every=3, progress=False)
    frames = imageio.mimread(gif)
    assert {f.shape[:2] for f in frames} == {(96, 128)}  # 2 x 2 cells, one black
    assert [len(r) for r in runs] == [2, 2, 2]
    strip = tmp_path / "strip.png"
    record_grid(players, strip, TASKS[:2], max_steps=12, progress=False, cols=3, strip_frames=4)
    assert imageio.imread(strip).shape == (2 * 48, 4 * 3 * 64, 3)  # a row per episode
    for p in players:
        p.env.close()


def test_render_cli_plays_a_model_on_a_test_set_and_counts_real_steps(model_zip, tmp_path, capsys):
    out = tmp_path / "model.mp4"
    args = ["render", "--model", str(model_zip), "--env", "stump-tracks", "--test-set", "grid"]
    args += ["--episodes", "2", "--width", "96", "--height", "64", "--max-steps", "40"]
    assert main(args + ["--out", str(out)]) == 0
    captured = capsys.readouterr()
    lengths = [int(n) for n in re.findall(r"length (\d+)", captured.out)]
    assert len(lengths) == 2 and imageio.get_reader(out).count_frames() == sum(lengths) + 2
    counts = [int(n) for n in re.findall(r"(\d+)step \[", captured.err)]
    assert counts[-1] == sum(lengths)  # the progress bar ends at the steps really played


def test_render_cli_compares_models_side_by_side(model_zip, tmp_path, capsys):
    out = tmp_path / "grid.png"
    args = ["render", "--compare", str(model_zip), str(model_zip), "--env", "stump-tracks"]
    args += ["--task", "stump_height=1,obstacle_spacing=4", "--width", "80", "--height", "60"]
    args += ["--max-steps", "20", "--no-progress", "--strip-frames", "3", "--out", str(out)]
    assert main(args) == 0
    assert imageio.imread(out).shape == (60, 3 * 2 * 80, 3)
    assert capsys.readouterr().out.count("model: episode 0") == 2


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--out", "x.avi"], "extension"),
        (["--format", "gif", "--out", "x.mp4"], "contradicts"),
        (["--every", "0"], "--every"),
        (["--task", "stump_height=1", "--task", "stump_height=2", "--episodes", "2"], "repeats"),
    ],
)
def test_render_cli_rejects_bad_options(extra, message, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["render", "--no-progress", *extra]) == 2
    assert message in capsys.readouterr().err
    assert not list(tmp_path.iterdir())  # nothing written
