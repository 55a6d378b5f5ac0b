"""ALP-GMM learns a batch of episodes exactly as it learns them one by one."""

from __future__ import annotations

import numpy as np
import pytest

from acl3d.task_space import TaskSpace
from acl3d.teachers import make


def _space() -> TaskSpace:
    from acl3d.envs.track_env import TrackEnv

    return TrackEnv().task_space


@pytest.mark.parametrize("max_size", [None, 60])
def test_update_batch_equals_episodic_updates_across_refits(max_size):
    space = _space()
    params = dict(fit_rate=40, nb_bootstrap=40, alp_buffer_size=25, alp_max_size=max_size)
    one = make("alp-gmm", space, seed=3, **params)
    many = make("alp-gmm", space, seed=3, **params)
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


def test_batches_cross_several_tree_rebuilds_as_single_pairs_do():
    """Batches larger than the neighbour buffer rebuild the tree where pairs one by one would:
    the same progress, the same tree bounds, with and without a maximum size."""
    from acl3d.teachers.alp_gmm import NearestNeighbourALP

    rng = np.random.default_rng(1)
    for max_size in (None, 20):
        one, many = (NearestNeighbourALP(2, buffer_size=7, max_size=max_size) for _ in range(2))
        for size in (3, 16, 1, 0, 40, 5, 1200):  # the last one grows the storage too
            # tasks on a coarse grid: exact and near ties between neighbours
            tasks, rewards = rng.integers(0, 6, (size, 2)) / 7.0, rng.normal(0.0, 1.0, size)
            alps = many.compute_batch(tasks, rewards)
            np.testing.assert_array_equal(alps, [one.compute(t, r) for t, r in zip(tasks, rewards)])
        a, b = one.state(), many.state()
        assert (a["tree_start"], a["tree_end"]) == (b["tree_start"], b["tree_end"])
        np.testing.assert_array_equal(a["tasks"], b["tasks"])
        np.testing.assert_array_equal(a["rewards"], b["rewards"])
