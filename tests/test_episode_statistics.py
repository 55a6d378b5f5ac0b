"""The episode-statistics layer: each episode summed once, the same on numpy and torch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from acl3d.envs.episode_statistics import EpisodeBatch, EpisodeStatistics, TeacherSync
from acl3d.teachers import make

N, DIM = 4, 2


def play(stats: EpisodeStatistics, steps: int, seed: int = 0):
    """Random rewards and endings; every ended env restarts on task [step, env]."""
    rng = np.random.default_rng(seed)
    stats.begin(np.arange(N), np.zeros((N, DIM)))
    out = []
    for t in range(steps):
        rewards = rng.normal(size=N)
        terminated = rng.random(N) < 0.2
        truncated = rng.random(N) < 0.1
        success = rng.random(N) < 0.5
        done = stats.step(rewards, terminated, truncated, success)
        ended = np.flatnonzero(np.asarray(done))
        tasks = np.array([[t, i] for i in ended], np.float32).reshape(-1, DIM)
        stats.begin(ended, tasks)
        out.append((rewards, terminated, truncated, success))
    return out


def reference(history):
    """Sums written out per env, per step."""
    ret, length, task = np.zeros(N), np.zeros(N, int), np.zeros((N, DIM))
    episodes = []
    for t, (rewards, term, trunc, success) in enumerate(history):
        for i in range(N):
            ret[i] += rewards[i]
            length[i] += 1
            if term[i] or trunc[i]:
                episodes.append(
                    (
                        i,
                        *task[i],
                        ret[i],
                        length[i],
                        success[i],
                        trunc[i] and not term[i],
                        (t + 1) * N,
                    )
                )
                ret[i], length[i], task[i] = 0.0, 0, (t, i)
    return episodes


def rows(batch: EpisodeBatch):
    b = batch.numpy()
    return [
        (int(i), *task, r, int(n), bool(s), bool(tr), int(ts))
        for i, task, r, n, s, tr, ts in zip(
            b.env_ids, b.tasks, b.returns, b.lengths, b.successes, b.truncated, b.total_steps
        )
    ]


@pytest.mark.parametrize("device", [None, "cpu"])
def test_episodes_are_summed_once_and_emitted_in_order(device):
    stats = EpisodeStatistics(N, DIM, device=device)
    history = play(stats, 50)
    got = rows(stats.pop())
    want = reference(history)
    assert len(got) == len(want) > 10
    for g, w in zip(got, want):
        assert g[:3] == tuple(w[:3]) and g[3] == pytest.approx(w[3]) and g[4:] == tuple(w[4:])
    assert len(stats.pop()) == 0


def test_torch_and_numpy_agree_and_torch_stays_tensors():
    a, b = EpisodeStatistics(N, DIM), EpisodeStatistics(N, DIM, device="cpu")
    play(a, 30, seed=3), play(b, 30, seed=3)
    pa, pb = a.pop(), b.pop()
    assert isinstance(pb.returns, torch.Tensor) and pb.returns.dtype == torch.float64
    for name in ("env_ids", "tasks", "returns", "lengths", "successes", "truncated", "total_steps"):
        np.testing.assert_array_equal(getattr(pa, name), getattr(pb.numpy(), name))


@pytest.mark.parametrize("device", [None, "cpu"])
def test_mask_begin_and_success_threshold(device):
    stats = EpisodeStatistics(2, 1, device=device, success_return=1.5)
    stats.begin(np.array([True, True]), np.array([[1.0], [2.0]]), initial_obs=np.ones((2, 3)))
    stats.step([1.0, 2.0], [False, True], [False, False])
    stats.begin(np.array([False, True]), np.array([[9.0], [5.0]]), initial_obs=np.zeros((2, 3)))
    stats.step([1.0, 1.0], [True, True], [False, False])
    b = stats.pop().numpy()
    assert b.env_ids.tolist() == [1, 0, 1]
    assert b.tasks[:, 0].tolist() == [2.0, 1.0, 5.0]  # env 0 kept its task
    assert b.returns.tolist() == [2.0, 2.0, 1.0] and b.successes.tolist() == [True, True, False]
    assert b.initial_obs.sum(axis=1).tolist() == [3.0, 3.0, 0.0]


@pytest.mark.parametrize("device", [None, "cpu"])
def test_add_sums_without_booking_an_episode(device):
    stats = EpisodeStatistics(2, 1, device=device)
    stats.begin([0, 1], np.array([[1.0], [2.0]]))
    for _ in range(3):
        stats.add([1.5, -1.0])
    assert len(stats.pop()) == 0 and stats.total_steps == 6
    assert np.asarray(stats.returns).tolist() == [4.5, -3.0]
    assert np.asarray(stats.lengths).tolist() == [3, 3]


def test_state_round_trip_continues_the_running_episodes():
    a = EpisodeStatistics(N, DIM)
    play(a, 7)
    a.pop()
    b = EpisodeStatistics(N, DIM, device="cpu")
    b.load_state_dict(a.state_dict())
    for s in (a, b):
        s.step(np.ones(N), np.ones(N, bool), np.zeros(N, bool))
    np.testing.assert_array_equal(a.pop().returns, b.pop().numpy().returns)


def test_bad_input_names_the_parameter():
    stats = EpisodeStatistics(N, DIM)
    with pytest.raises(ValueError, match="env_ids"):
        stats.begin([0, N], np.zeros((2, DIM)))
    with pytest.raises(ValueError, match="tasks"):
        stats.begin([0, 1], np.zeros((3, DIM)))
    with pytest.raises(ValueError, match="num_envs"):
        EpisodeStatistics(0, DIM)


def test_teacher_sync_learns_then_samples():
    teacher = make("random", {"a": (0.0, 1.0), "b": (0.0, 1.0)}, seed=0)
    sync = TeacherSync(teacher)
    tasks = sync.sync(EpisodeBatch.empty(2), np.arange(3))
    assert tasks.shape == (3, 2) and tasks.dtype == np.float32
    stats = EpisodeStatistics(3, 2)
    stats.begin(np.arange(3), tasks)
    stats.step(np.ones(3), [True, False, True], np.zeros(3, bool))
    finished = stats.pop()
    assert sync.sync(finished, finished.env_ids).shape == (2, 2)
    assert teacher.nb_episodes == 2
    with pytest.raises(ValueError, match="teacher"):
        TeacherSync(object())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_steps_need_no_host_sync_and_match_numpy():
    """On a GPU, `step` and a masked `begin` never read back to the host (checked on an H200)."""
    n, steps, dev = 1024, 50, "cuda"
    g = torch.Generator(device=dev).manual_seed(0)
    rewards = torch.randn(steps, n, device=dev, generator=g)
    ends = torch.rand(steps, n, device=dev, generator=g) < 0.02
    tasks = torch.rand(steps, n, DIM, device=dev, generator=g)
    a, b = EpisodeStatistics(n, DIM, device=dev), EpisodeStatistics(n, DIM)
    a.begin(torch.ones(n, dtype=torch.bool, device=dev), tasks[0])
    b.begin(np.arange(n), tasks[0].cpu().numpy())
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        for t in range(steps):
            a.begin(a.step(rewards[t], ends[t], torch.zeros_like(ends[t])), tasks[t])
    finally:
        torch.cuda.set_sync_debug_mode(0)
    for t in range(steps):
        done = b.step(rewards[t].cpu().numpy(), ends[t].cpu().numpy(), np.zeros(n, bool))
        b.begin(np.flatnonzero(done), tasks[t].cpu().numpy()[done])
    pa, pb = a.pop().numpy(), b.pop()
    assert len(pa) == len(pb) > 0
    for name in ("env_ids", "tasks", "returns", "lengths", "total_steps"):
        np.testing.assert_array_equal(getattr(pa, name), getattr(pb, name))
