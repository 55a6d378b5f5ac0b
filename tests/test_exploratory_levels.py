"""Robust PLR's "no policy update on new levels": the transitions of exploratory episodes (new or
edited levels) are left out of the student's updates (PPO and SAC), on real training runs."""

from __future__ import annotations

from collections import Counter

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from test_resume import STEPS, assert_same_run

from acl3d.campaign.options import check_options, parse_set
from acl3d.cli import main
from acl3d.teachers.controller import TeacherController
from acl3d.teachers.state_files import load_state
from acl3d.training import students, train
from acl3d.training.exclusion import (
    ExcludingPPO,
    ExcludingReplayBuffer,
    ExcludingRolloutBuffer,
)
from acl3d.training.run_dir import RunDir

# 2 envs, 60-step episodes, 256-step rollouts; an 8-level buffer replays from its 4th level on.
RUN = {
    "env": "stump-tracks",
    "teacher": "robust-plr",
    "student": "ppo",
    "preset": "fast",
    "n_envs": 2,
    "seed": 5,
    "steps": STEPS,
    "eval_every": 512,
    "checkpoint_every": 256,
    "periodical_samples_every": 256,
    "student_params": {"n_steps": 128, "batch_size": 64},
    "teacher_params": {"buffer_size": 8},
    "env_kwargs": {"max_episode_steps": 60},
    "nb_test_episodes": 4,
    "progress_bar": False,
    "verbose": 0,
}


SAC = {
    "student": "sac",
    "student_params": {"learning_starts": 100, "batch_size": 64, "buffer_size": 4096},
}


class StepRecorder(BaseCallback):
    """Every step's dones, the exclusion flags the student's buffer stored for every step (PPO:
    at each rollout end; SAC, whose buffer holds the whole run: at the end), the kept count of
    every PPO rollout, and the policy weights at the start."""

    def __init__(self):
        super().__init__()
        self.excluded, self.dones, self.kept = [], [], []
        self.initial = None

    def _on_training_start(self) -> None:
        self.initial = {k: v.clone() for k, v in self.model.policy.state_dict().items()}

    def _on_step(self) -> bool:
        self.dones.append(np.asarray(self.locals["dones"]).copy())
        return True

    def _on_rollout_end(self) -> None:
        if hasattr(self.model, "rollout_buffer"):
            self.excluded.extend(self.model.rollout_buffer.excluded.copy())
            self.kept.append(self.model.rollout_buffer.kept)

    def _on_training_end(self) -> None:
        if hasattr(self.model, "replay_buffer"):
            buffer = self.model.replay_buffer
            assert not buffer.full
            self.excluded = list(buffer.excluded[: buffer.pos].copy())


def episodes_from_steps(excluded, dones) -> list[tuple[bool, int]]:
    """(excluded, length) of every finished episode in the order they finished; each episode's
    transitions must all carry the same flag."""
    n_envs = len(dones[0])
    running = [[] for _ in range(n_envs)]
    out = []
    for flags, done in zip(excluded, dones):
        for i in range(n_envs):
            running[i].append(bool(flags[i]))
            if done[i]:
                assert len(set(running[i])) == 1, "an episode is partly excluded"
                out.append((running[i][0], len(running[i])))
                running[i] = []
    return out


# tasks pulled at reset (batched) or queued ahead (dummy); PPO's rollout / SAC's replay buffer
@pytest.mark.parametrize(
    "vec_env, student", [("batched", "ppo"), ("dummy", "ppo"), ("dummy", "sac")]
)
def test_excluded_transitions_are_those_of_the_teachers_exploratory_episodes(
    vec_env, student, tmp_path
):
    rec = StepRecorder()
    changes = SAC if student == "sac" else {}
    train({**RUN, **changes}, vec_env=vec_env, out=str(tmp_path / "run"), callbacks=[rec])
    dump = load_state(tmp_path / "run" / "teacher")
    marked = list(dump["teacher_bk"]["exploratory"])
    assert 0 < sum(marked) < len(marked)  # both kinds were played
    finished = episodes_from_steps(rec.excluded, rec.dones)
    assert [flag for flag, _ in finished] == marked
    assert [length for _, length in finished] == list(dump["train_lengths"])
    total = sum(int(np.count_nonzero(f)) for f in rec.excluded)
    if student == "ppo":
        assert sum(rec.kept) == STEPS - total
    else:  # the replay buffer still holds every transition with its flag
        assert rec.model.replay_buffer.kept == STEPS - total
    assert RunDir(tmp_path / "run").read_section("resolved")["exclude_exploratory"] is True


@pytest.mark.parametrize("student", ["ppo", "sac"])
def test_new_levels_only_update_nothing(student, tmp_path):
    """With no replay every level is new: everything is excluded, and the student never moves."""
    rec = StepRecorder()
    params = {"buffer_size": 8, "replay_prob": 0.0}
    config = {**RUN, **(SAC if student == "sac" else {}), "teacher_params": params, "steps": 512}
    train(config, out=str(tmp_path / "run"), callbacks=[rec])
    assert rec.kept == ([0, 0] if student == "ppo" else [])
    assert all(flags.all() for flags in rec.excluded)
    final = rec.model.policy.state_dict()
    for key, value in rec.initial.items():
        assert torch.equal(value, final[key]), key


def test_off_trains_on_every_episode(tmp_path):
    run = train(RUN, steps=512, exclude_exploratory=False, out=str(tmp_path / "run"))
    assert RunDir(run.run_dir).read_section("resolved")["exclude_exploratory"] is False
    model = students.load("ppo", run.run_dir / "final_model.zip")
    assert model.rollout_buffer_class is RolloutBuffer  # SB3's own: every transition learned


def filled_buffer(n_steps: int, n_envs: int, excluded) -> ExcludingRolloutBuffer:
    """A full buffer whose observation at (step, env) is its own flat index."""
    space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)
    buffer = ExcludingRolloutBuffer(n_steps, space, gym.spaces.Box(-1, 1, (1,)), n_envs=n_envs)
    for t in range(n_steps):
        buffer.exclude_next(excluded[t])
        obs = np.array([[t * n_envs + i] for i in range(n_envs)], np.float32)
        buffer.add(obs, np.zeros((n_envs, 1)), np.zeros(n_envs), np.zeros(n_envs),
                   torch.zeros(n_envs), torch.zeros(n_envs))  # fmt: skip
    buffer.compute_returns_and_advantage(torch.zeros(n_envs), np.zeros(n_envs))
    return buffer


def test_the_buffer_yields_every_kept_transition_once_and_no_other():
    n_steps, n_envs = 16, 3
    excluded = np.random.default_rng(0).random((n_steps, n_envs)) < 0.4
    buffer = filled_buffer(n_steps, n_envs, excluded)
    assert buffer.kept == np.count_nonzero(~excluded)
    batches = [b.observations.numpy().reshape(-1).astype(int) for b in buffer.get(batch_size=5)]
    assert [len(b) for b in batches[:-1]] == [5] * (len(batches) - 1)
    seen = np.concatenate(batches)
    assert sorted(seen) == list(np.flatnonzero(~excluded.reshape(-1)))
    buffer.reset()
    assert buffer.kept == n_steps * n_envs


def test_the_replay_buffer_samples_kept_transitions_only_and_sb3s_when_none_excluded():
    space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)
    buffers = [cls(120, space, gym.spaces.Box(-1, 1, (1,)), n_envs=3)  # 40 steps
               for cls in (ExcludingReplayBuffer, ExcludingReplayBuffer, ReplayBuffer)]  # fmt: skip
    excluded = np.random.default_rng(1).random((40, 3)) < 0.7
    for t in range(40):
        obs = np.array([[3 * t + i] for i in range(3)], np.float32)
        buffers[0].exclude_next(excluded[t])
        for b in buffers:
            b.add(obs, obs, np.zeros((3, 1)), np.zeros(3), np.zeros(3), [{}] * 3)
    assert buffers[0].kept == np.count_nonzero(~excluded)
    np.random.seed(0)
    seen = buffers[0].sample(4000).observations.numpy().reshape(-1).astype(int)
    kept = np.flatnonzero(~excluded.reshape(-1))
    assert set(seen) == set(kept)  # every kept one, no other
    counts = np.bincount(seen)[kept]  # uniform: about 4000 / 36 each
    assert counts.min() > 0.5 * counts.mean() and counts.max() < 1.5 * counts.mean()
    draws = []
    for b in buffers[1:]:  # nothing excluded: SB3's own samples
        np.random.seed(0)
        draws.append(b.sample(50).observations.numpy())
    np.testing.assert_array_equal(*draws)
    buffers[0].set_excluded(np.ones((40, 3), bool))
    with pytest.raises(ValueError, match="no kept transition"):
        buffers[0].sample(4)


def test_the_buffer_excluding_nothing_is_sb3s():
    n_steps, n_envs = 8, 2
    plain = filled_buffer(n_steps, n_envs, np.zeros((n_steps, n_envs), bool))
    np.random.seed(3)
    ours = [b.observations.numpy().copy() for b in plain.get(batch_size=4)]
    sb3 = RolloutBuffer(n_steps, plain.observation_space, plain.action_space, n_envs=n_envs)
    for t in range(n_steps):
        obs = np.array([[t * n_envs + i] for i in range(n_envs)], np.float32)
        sb3.add(obs, np.zeros((n_envs, 1)), np.zeros(n_envs), np.zeros(n_envs),
                torch.zeros(n_envs), torch.zeros(n_envs))  # fmt: skip
    sb3.compute_returns_and_advantage(torch.zeros(n_envs), np.zeros(n_envs))
    np.random.seed(3)
    theirs = [b.observations.numpy() for b in sb3.get(batch_size=4)]
    for a, b in zip(ours, theirs, strict=True):
        np.testing.assert_array_equal(a, b)


def test_ppo_with_nothing_excluded_is_sb3s_ppo():
    def weights(cls, **kwargs):
        model = cls("MlpPolicy", "Pendulum-v1", n_steps=64, batch_size=32, n_epochs=2, seed=1,
                    device="cpu", **kwargs)  # fmt: skip
        model.learn(128)
        return model.policy.state_dict()

    ours = weights(ExcludingPPO, rollout_buffer_class=ExcludingRolloutBuffer)
    theirs = weights(PPO)
    for key in theirs:
        assert torch.equal(ours[key], theirs[key]), key


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"exclude_exploratory": "yes"}, "exclude_exploratory='yes'; valid"),
        ({"exclude_exploratory": 1}, "exclude_exploratory=1; valid"),
        ({"exclude_exploratory": True, "teacher": "alp-gmm"}, "marks no exploratory levels"),
        (
            {
                "exclude_exploratory": True,
                "student": "sac",
                "student_params": {"optimize_memory_usage": True},
            },
            "optimize_memory_usage=True",
        ),  # fmt: skip
    ],
)
def test_bad_settings_are_refused_before_the_run_starts(changes, message, tmp_path):
    with pytest.raises(ValueError, match=message):
        train(RUN, **changes, out=str(tmp_path / "run"))
    assert not (tmp_path / "run").exists()


def test_cli_option(tmp_path, capsys):
    assert main(["train", "--teacher", "random", "--exclude-exploratory", "on",
                 "--out", str(tmp_path / "a")]) == 2  # fmt: skip
    assert "marks no exploratory levels" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "--exclude-exploratory", "maybe", "--out", str(tmp_path / "b")])
    # campaign specs take it as a training option (YAML's off is False)
    assert parse_set(["exclude_exploratory=off"]) == {"exclude_exploratory": False}
    check_options({"exclude_exploratory": "auto", "teacher": "accel"}, "spec")


@pytest.mark.parametrize("student", ["ppo", "sac"])
def test_resume_is_exact_with_exclusions(student, tmp_path):
    """A run stopped at a checkpoint and resumed (queued tasks' flags and SAC's stored flags
    included, dummy vec env) ends bit for bit as the run that never stopped."""
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    config = {**RUN, **(SAC if student == "sac" else {}), "vec_env": "dummy"}
    train(config, out=str(whole))
    train(config, steps=STEPS // 2, out=str(parts))
    train(resume=parts, steps=STEPS, progress_bar=False)
    assert_same_run(whole, parts)


@pytest.mark.parametrize("teacher", ["robust-plr", "accel"])
def test_flags_at_sampling_are_the_teachers_own_with_shuffled_dimensions(teacher):
    """The controller flags each task when it samples it (in the teacher's space); the teacher
    recognises its shuffled, float32 proposals when their outcomes come back in any order. (Two
    proposals of the same vector in flight, e.g. ACCEL edits clipped to a corner, cannot be told
    apart: they may swap their flags, so levels are compared with their flags as multisets.)"""
    space = {"stump_height": [0.0, 3.0], "obstacle_spacing": [0.0, 6.0]}
    controller = TeacherController(
        teacher, space, 0, shuffle_dimensions=True, teacher_params={"buffer_size": 8}
    )
    rng, reported, in_flight = np.random.default_rng(0), [], []
    for _ in range(300):
        in_flight.append(controller.sample_training_task())
        if len(in_flight) == 4:
            task, flag = in_flight.pop(int(rng.integers(4)))
            reported.append((tuple(np.round(task, 4)), flag))  # edits may come back ~1e-16 off
            controller.record_episode(task, float(rng.uniform(0, 200)), 10, False)
    marked = controller.teacher.bk["exploratory"]
    assert Counter(zip([t for t, _ in reported], marked)) == Counter(reported)
    if teacher == "robust-plr":  # uniform new levels never repeat: the same order
        assert marked == [flag for _, flag in reported]
    assert 0 < marked.count(False) < len(marked)
    assert not TeacherController("alp-gmm", space, 0).sample_training_task()[1]
