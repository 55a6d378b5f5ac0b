"""Snapshots stacked into one policy act as each alone: block b's actions are snapshot b's,
bit for bit on the CPU, sampled or mean, whatever the other blocks hold."""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("rsl_rl")

from acl3d.training.torch_student import rsl_ppo  # noqa: E402
from acl3d.training.torch_student.policy_stack import PolicyStack  # noqa: E402

SPEC = {"student": "rsl-ppo", "observation_size": 12, "action_size": 3, "hidden_dims": [32, 16],
        "activation": "elu", "init_noise_std": 1.0, "min_noise_std": 0.3}  # fmt: skip
WORLDS = 50


def _snapshot(seed: int, spec=SPEC) -> rsl_ppo.PolicySnapshot:
    """A snapshot with its own weights, normaliser statistics and noise (some under the floor)."""
    torch.manual_seed(seed)
    actor = rsl_ppo._models(spec, 1, "cpu")[0]
    with torch.no_grad():
        actor.obs_normalizer._mean.normal_()
        actor.obs_normalizer._std.uniform_(0.5, 2.0)
        actor.distribution.std_param.uniform_(0.1, 1.0)
    return rsl_ppo.PolicySnapshot(spec, actor, -1.0, 1.0)


def _generators(seeds):
    return [None if s is None else torch.Generator().manual_seed(s) for s in seeds]


@pytest.mark.parametrize("seeds", [(None, None, None), (5, 6, 7), (5, None, 7)])
def test_each_block_acts_as_its_snapshot_alone(seeds):
    snapshots = [_snapshot(k) for k in range(3)]
    obs = 3.0 * torch.randn(3 * WORLDS, SPEC["observation_size"])
    stacked = PolicyStack(snapshots)(obs, _generators(seeds))
    alone = torch.cat([
        s(obs[b * WORLDS : (b + 1) * WORLDS], g)
        for b, (s, g) in enumerate(zip(snapshots, _generators(seeds), strict=True))
    ])  # fmt: skip
    assert torch.equal(stacked, alone)
    assert stacked.abs().max() <= 1.0


def test_a_block_does_not_depend_on_its_neighbours():
    first, obs = _snapshot(0), torch.randn(2 * WORLDS, SPEC["observation_size"])
    beside_one = PolicyStack([first, _snapshot(1)])(obs, _generators([3, 4]))
    other_obs = torch.cat([obs[:WORLDS], torch.randn(WORLDS, SPEC["observation_size"])])
    beside_other = PolicyStack([first, _snapshot(2)])(other_obs, _generators([3, 9]))
    assert torch.equal(beside_one[:WORLDS], beside_other[:WORLDS])


def test_bad_stacks_are_refused():
    other = dict(SPEC, hidden_dims=[8])
    with pytest.raises(ValueError, match="snapshots: a stack plays snapshots of one spec"):
        PolicyStack([_snapshot(0), _snapshot(1, other)])
    stack = PolicyStack([_snapshot(0), _snapshot(1)])
    with pytest.raises(ValueError, match=r"generators: one a block \(2\), got 1"):
        stack(torch.zeros(2 * WORLDS, SPEC["observation_size"]), [None])
