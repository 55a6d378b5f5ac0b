"""The rules are written once (`acl3d.envs.array_ops`): the same objects on numpy and on torch.

On a CPU env's physics, the rules on float64 numpy arrays (the CPU envs) and the same rules on
float64 torch tensors (`rules.on(TorchOps)`, what the many-world simulation runs in float32) give
the same outcome: observation, reward, termination, shaping, critical contact, success and servo
commands. No MuJoCo Warp needed: the torch side reads the env's MjData through a `Simulation`-like
view in Warp's layout.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from acl3d.envs import make
from acl3d.envs.array_ops import NUMPY, TorchOps

TORCH64 = TorchOps("cpu", torch.float64)


class TorchView:
    """One env's MjData as (1, ...) torch tensors in MuJoCo Warp's layout (xmat (1, nbody, 3,
    3)), with force caps of its own: what the rules on torch read and write."""

    def __init__(self, env):
        data, model = env.data, env.model
        self._fields = {
            name: torch.from_numpy(getattr(data, name).copy()[None])
            for name in ("qpos", "qvel", "ctrl", "xpos", "cvel", "sensordata")
        }
        self._fields["xmat"] = torch.from_numpy(data.xmat.copy().reshape(1, -1, 3, 3))
        self.caps = torch.from_numpy(model.actuator_forcerange.copy()[None])

    def field(self, name):
        return self._fields[name]

    def set_force_caps(self, index, ranges):
        self.caps[:, index] = ranges


CASES = [
    ("stump-tracks", {"body": "classic_bipedal"}),
    ("stump-tracks", {"body": "spider", "planar": False}),
    ("hexagon-tracks", {"body": "classic_bipedal"}),
    ("terrain3d", {"body": "big_quadru"}),
    ("terrain3d", {"body": "classic_bipedal"}),
]


@pytest.mark.parametrize("name, kwargs", CASES)
def test_the_rules_on_torch_equal_the_rules_on_numpy(name, kwargs):
    env = make(name, **kwargs).unwrapped
    env.reset(seed=3)
    rng = np.random.default_rng(3)
    for _ in range(20):  # into the episode: contacts, lidar hits
        env.step(rng.uniform(-1.0, 1.0, env.action_space.shape))
    rules, rows = env.rules, env.rows
    on_torch = rules.on(TORCH64)
    view = TorchView(env)
    heights = torch.from_numpy(rows.heights.copy())
    actions = rng.uniform(-1.5, 1.5, (1, env.action_space.shape[0]))
    prev = rows.prev_shaping.copy()

    out_np = rules.outcome(env.physics, actions, rows.heights, prev)
    out_t = on_torch.outcome(view, torch.from_numpy(actions), heights, torch.from_numpy(prev))
    np.testing.assert_allclose(out_t.obs.numpy(), out_np.obs, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out_t.reward.numpy(), out_np.reward, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out_t.shaping.numpy(), out_np.shaping, rtol=1e-12, atol=1e-12)
    assert np.array_equal(out_t.terminated.numpy(), out_np.terminated)
    assert np.array_equal(out_t.critical.numpy(), out_np.critical)
    assert (out_t.crossed is None) == (out_np.crossed is None)
    returns = np.array([rules.success_return + 1.0 if name != "terrain3d" else 0.0])
    assert np.array_equal(
        on_torch.success(torch.from_numpy(returns), out_t).numpy(),
        rules.success(returns, out_np),
    )

    rules.servo(actions, env.physics)
    on_torch.servo(torch.from_numpy(actions), view)
    np.testing.assert_array_equal(view.caps[0].numpy(), env.model.actuator_forcerange)
    np.testing.assert_array_equal(view.field("ctrl")[0].numpy(), env.data.ctrl)


def test_a_ray_cast_sensor_has_no_torch_form():
    env = make("terrain3d", body="classic_bipedal", observation="lidar").unwrapped
    with pytest.raises(ValueError, match="observation=Lidar"):
        env.rules.on(TORCH64)


@pytest.mark.parametrize("n", [1, 2, 7])
def test_the_operations_that_differ_agree_between_libraries(n):
    rng = np.random.default_rng(n)
    rows = np.sort(rng.integers(0, 6, (n, 9)).astype(float), axis=1)  # ties included
    values = np.array([-1.0, 0.0, 2.0, 2.5, 5.0, 9.0])
    expected = (rows[:, None, :] < values[:, None]).sum(axis=2)
    assert np.array_equal(NUMPY.count_below(rows, values), expected)
    t_rows, t_values = torch.from_numpy(rows), torch.from_numpy(values)
    assert np.array_equal(TORCH64.count_below(t_rows, t_values).numpy(), expected)

    a, index = rng.normal(size=(n, 11)), rng.integers(0, 11, (n, 4))
    np.testing.assert_array_equal(NUMPY.gather(a, index), np.take_along_axis(a, index, 1))
    got = TORCH64.gather(torch.from_numpy(a), torch.from_numpy(index)).numpy()
    np.testing.assert_array_equal(got, np.take_along_axis(a, index, 1))
    start = rng.integers(0, 5, (n, 1))
    for source in (a, a[0]):  # rows of their own, or one row shared
        expected = np.take_along_axis(np.broadcast_to(source, a.shape), start + np.arange(6), 1)
        window = NUMPY.window(source, start, 6)
        np.testing.assert_array_equal(window, expected)
        window[:] = np.nan  # a copy: the source stays as it was
        assert not np.isnan(source).any()
        got = TORCH64.window(torch.from_numpy(source), torch.from_numpy(start), 6).numpy()
        np.testing.assert_array_equal(got, expected)
    column = a[:, 2:3]  # one value per row, broadcast against the rows
    np.testing.assert_array_equal(a - NUMPY.per_row(column), a - column)
    np.testing.assert_array_equal(NUMPY.per_row(column) * a[:, :4], column * a[:, :4])
    np.testing.assert_array_equal(NUMPY.running_max(a), np.maximum.accumulate(a, axis=1))
    np.testing.assert_array_equal(
        TORCH64.running_max(torch.from_numpy(a)).numpy(), np.maximum.accumulate(a, axis=1)
    )
    np.testing.assert_array_equal(NUMPY.clip(a, -0.5, 0.5), np.clip(a, -0.5, 0.5))
    np.testing.assert_array_equal(
        TORCH64.clip(torch.from_numpy(a), high=0.5).numpy(), np.minimum(a, 0.5)
    )
    y, x = a[:, 0], a[:, 1]
    np.testing.assert_allclose(NUMPY.atan2(y, x), np.arctan2(y, x), rtol=1e-15, atol=0)
    np.testing.assert_allclose(
        TORCH64.atan2(torch.from_numpy(y), torch.from_numpy(x)).numpy(), np.arctan2(y, x),
        rtol=1e-15, atol=0,
    )  # fmt: skip


@pytest.mark.parametrize("n", [1, 3])
def test_sparse_work_gives_the_same_minima_on_both_libraries(n):
    """numpy computes only the pairs a mask keeps; torch computes every pair and masks: the
    per-row minima agree."""
    rng = np.random.default_rng(n)
    mask = rng.random((n, 5)) < 0.4
    values = rng.normal(size=(n, 5, 2))  # a value per (row, col) pair and per ray

    def minima(ops, mask, values):
        rows, cols = ops.pairs(mask)
        picked = ops.xp.where(mask[rows, cols][None], values[rows, cols].T, np.inf)
        return ops.scatter_min(picked, rows, n)

    expected = np.where(mask[..., None], values, np.inf).min(axis=1)
    np.testing.assert_array_equal(minima(NUMPY, mask, values), expected)
    got = minima(TORCH64, torch.from_numpy(mask), torch.from_numpy(values))
    np.testing.assert_array_equal(got.numpy(), expected)
    assert NUMPY.needed(mask) == bool(mask.any()) and TORCH64.needed(torch.from_numpy(mask))
