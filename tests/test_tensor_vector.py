"""The CPU tensor vector env plays exactly what the numpy batched vector env plays."""

from __future__ import annotations

import numpy as np
import torch
from gymnasium.vector import AutoresetMode

from acl3d.envs.batched_vector import BatchedVectorEnv
from acl3d.envs.tensor_vector import CpuTensorVectorEnv


class _Tasks:
    """A curriculum cycling through fixed tasks, recording the finished episodes."""

    def __init__(self, tasks):
        self.tasks, self.count, self.reports = tasks, 0, []

    def sync(self, finished, env_ids):
        self.reports += list(zip(finished.env_ids.tolist(), finished.returns.tolist()))
        out = []
        for _ in env_ids:
            self.count += 1
            out.append(self.tasks[self.count % len(self.tasks)])
        return np.asarray(out, np.float32).reshape(len(env_ids), -1)


def _tasks(space):
    low, high = space.low, space.high
    return [low + (high - low) * f for f in (0.1, 0.5, 0.9)]


def test_matches_numpy_vector_env_bit_for_bit():
    n, steps, limit = 3, 60, 25  # short episodes: autoresets and final observations happen
    vec = BatchedVectorEnv(
        "stump-tracks", n, autoreset_mode=AutoresetMode.SAME_STEP, max_episode_steps=limit
    )
    source_np = _Tasks(_tasks(vec.task_space))
    vec.curriculum_sync = source_np
    tens = CpuTensorVectorEnv("stump-tracks", n, max_episode_steps=limit)
    source_t = _Tasks(_tasks(tens.task_space))
    tens.vector.curriculum_sync = source_t
    try:
        obs_np, _ = vec.reset(seed=5)
        obs_t = tens.reset(seed=5)
        assert obs_t.dtype == torch.float32 and obs_t.shape == (n, tens.observation_size)
        np.testing.assert_array_equal(obs_t.numpy(), obs_np)
        rng = np.random.default_rng(0)
        ended = 0
        for _ in range(steps):
            actions = rng.uniform(-1, 1, (n, tens.action_size)).astype(np.float32)
            o, r, te, tr, info = vec.step(actions)
            ot, rt, tet, trt, extras = tens.step(torch.from_numpy(actions))
            np.testing.assert_array_equal(ot.numpy(), o)
            np.testing.assert_array_equal(rt.numpy(), r.astype(np.float32))
            np.testing.assert_array_equal(tet.numpy(), te)
            np.testing.assert_array_equal(trt.numpy(), tr)
            done = te | tr
            final = extras["final_obs"].numpy()
            for i in range(n):
                want = info["final_obs"][i] if done[i] else o[i]
                np.testing.assert_array_equal(final[i], want)
            ended += int(done.sum())
        assert ended >= n  # every world reset at least once
        assert source_t.reports == source_np.reports
    finally:
        vec.close()
        tens.close()


def test_state_round_trip_continues_exactly():
    n = 2
    a = CpuTensorVectorEnv("stump-tracks", n, max_episode_steps=30)
    b = CpuTensorVectorEnv("stump-tracks", n, max_episode_steps=30)
    rng = np.random.default_rng(1)
    actions = [torch.from_numpy(rng.uniform(-1, 1, (n, a.action_size))) for _ in range(40)]
    try:
        a.reset(seed=3)
        b.reset(seed=99)
        for act in actions[:10]:
            a.step(act)
        b.set_state(a.get_state())
        for act in actions[10:]:
            out_a, out_b = a.step(act), b.step(act)
            for x, y in zip(out_a[:4], out_b[:4]):
                assert torch.equal(x, y)
    finally:
        a.close()
        b.close()
