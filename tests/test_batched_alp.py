"""ALP-GMM learns a batch of episodes exactly as it learns them one by one."""

from __future__ import annotations

import numpy as np

from acl3d.task_space import TaskSpace
from acl3d.teachers import make


def _space() -> TaskSpace:
    from acl3d.envs.track_env import TrackEnv

    return TrackEnv().task_space


def test_update_batch_equals_episodic_updates_across_refits():
    space = _space()
    one = make("alp-gmm", space, seed=3, fit_rate=40, nb_bootstrap=40)
    many = make("alp-gmm", space, seed=3, fit_rate=40, nb_bootstrap=40)
    rng = np.random.default_rng(0)
    for size in (1, 7, 50, 3, 64, 0, 90):  # batches across the buffer and refit points
        tasks = rng.uniform(space.low, space.high, (size, space.dim))
        returns = rng.normal(-40.0, 30.0, size)
        many.update_batch(tasks, returns, np.zeros(size, bool))
        for task, ret in zip(tasks, returns):
            one.episodic_update(task, float(ret), False)
    a, b = one.state_dict(), many.state_dict()
    np.testing.assert_array_equal(a["bk"]["tasks_alps"], b["bk"]["tasks_alps"])
    assert a["nb_episodes"] == b["nb_episodes"] == 215
    np.testing.assert_array_equal(a["extra"]["alp"]["tasks"], b["extra"]["alp"]["tasks"])
    np.testing.assert_equal(a["extra"], b["extra"])  # the same mixtures, fitted at the same points
    np.testing.assert_array_equal(one.sample_tasks(5), many.sample_tasks(5))
