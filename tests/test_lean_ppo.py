"""`LeanPPO` computes what rsl_rl's PPO computes, bit for bit: the same actions, stored
rollouts, losses, learning rates and weights over several rollouts, the same draws from the
global generator, and checkpoints that either class resumes."""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("rsl_rl")

from rsl_rl.algorithms import PPO  # noqa: E402
from rsl_rl.storage import RolloutStorage  # noqa: E402

from acl3d.training.torch_student import rsl_ppo  # noqa: E402
from acl3d.training.torch_student.lean_ppo import LeanPPO  # noqa: E402

N, T, OBS, ACT = 6, 16, 5, 3
SPEC = {"observation_size": OBS, "action_size": ACT, "hidden_dims": [16, 8],
        "activation": "elu", "init_noise_std": 1.0}  # fmt: skip
SETTINGS = dict(num_learning_epochs=3, num_mini_batches=4, entropy_coef=0.01, learning_rate=3e-3,
                desired_kl=0.01, schedule="adaptive", max_grad_norm=0.5)  # fmt: skip


def _algorithm(cls, seed: int = 0, **options):
    torch.manual_seed(seed)
    actor, critic, obs = rsl_ppo._models(SPEC, N, "cpu")
    storage = RolloutStorage("rl", N, T, obs, [ACT], "cpu")
    alg = cls(actor, critic, storage, device="cpu", **{**SETTINGS, **options})
    alg.train_mode()
    return alg


def _rollout(alg, data, lean: bool) -> list[torch.Tensor]:
    """One rollout of `data` (observations, rewards, dones); the actions taken."""
    taken = []
    with torch.inference_mode():
        for obs, rewards, dones in data[:-1]:
            if lean:
                taken.append(alg.act(obs))
                alg.record(rewards, dones)
            else:
                taken.append(alg.act(rsl_ppo._obs(obs)).clone())
                alg.process_env_step(None, rewards, dones, {})
        alg.compute_returns(rsl_ppo._obs(data[-1][0]))
    return taken


def _data(seed: int):
    g = torch.Generator().manual_seed(seed)
    return [
        (torch.randn(N, OBS, generator=g) * 3, torch.randn(N, generator=g),
         torch.rand(N, generator=g) < 0.1)
        for _ in range(T + 1)
    ]  # fmt: skip


def _weights(alg) -> list[torch.Tensor]:
    return [*alg.actor.state_dict().values(), *alg.critic.state_dict().values()]


def _same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return len(a) == len(b) and all(torch.equal(x, y) for x, y in zip(a, b))


def _train(alg, lean: bool, seeds) -> list:
    """Rollouts then updates on `seeds`' data: what each produced, in order."""
    out = []
    for seed in seeds:
        out.append(_rollout(alg, _data(seed), lean))
        stored = [alg.storage.returns.clone(), alg.storage.advantages.clone()]
        out += [stored, alg.update(), alg.learning_rate, _weights(alg)]
    return out


def _assert_same(left: list, right: list) -> None:
    assert len(left) == len(right)
    for a, b in zip(left, right):
        if isinstance(a, list):
            assert _same(a, b)
        else:
            assert a == b


@pytest.mark.parametrize("entropy_coef", [0.01, 0.0])  # 0: the `fast` preset's
@pytest.mark.parametrize("critic_thread", [True, False])
def test_lean_ppo_matches_rsl_rl_bit_for_bit(critic_thread, entropy_coef):
    reference = _algorithm(PPO, entropy_coef=entropy_coef)
    lean = _algorithm(LeanPPO, critic_thread=critic_thread, entropy_coef=entropy_coef)
    assert _same(_weights(reference), _weights(lean))
    torch.manual_seed(5)
    expected = _train(reference, False, (1, 2, 3))
    draw = torch.rand(4)
    torch.manual_seed(5)
    got = _train(lean, True, (1, 2, 3))
    _assert_same(expected, got)
    assert torch.equal(draw, torch.rand(4))  # the same draws from the global generator
    assert expected[-3] != 3e-3  # the adaptive learning rate moved: the KL path ran


def test_checkpoints_cross_between_the_two_classes():
    torch.manual_seed(7)
    lean = _algorithm(LeanPPO)
    _train(lean, True, (1,))
    saved = lean.save()
    assert len(saved["optimizer_state_dict"]["state"]) == len(list(lean.actor.parameters())) + len(
        list(lean.critic.parameters())
    )
    reference, resumed = _algorithm(PPO, seed=1), _algorithm(LeanPPO, seed=1)
    reference.load(saved, None, strict=True)
    resumed.load(reference.save(), None, strict=True)
    torch.manual_seed(9)
    expected = _train(reference, False, (2, 3))
    torch.manual_seed(9)
    _assert_same(expected, _train(resumed, True, (2, 3)))


def test_an_actor_whose_std_is_not_a_scalar_parameter_is_refused():
    torch.manual_seed(0)
    actor, critic, obs = rsl_ppo._models(SPEC, N, "cpu")
    actor.distribution.std_type = "log"  # its std would come from log_std_param
    storage = RolloutStorage("rl", N, T, obs, [ACT], "cpu")
    with pytest.raises(ValueError, match="scalar std"):
        LeanPPO(actor, critic, storage, device="cpu", **SETTINGS)


def test_a_full_rollout_refuses_another_step():
    lean = _algorithm(LeanPPO)
    data = _data(0)
    with torch.inference_mode():
        for obs, rewards, dones in data[:-1]:
            lean.act(obs)
            lean.record(rewards, dones)
        with pytest.raises(OverflowError, match="rollout is full"):
            lean.record(data[0][1], data[0][2])


def _excluding_update(actions_offset: float, excluded: torch.Tensor, shifted=None):
    """One rollout and update of an excluding `LeanPPO`, with `actions_offset` added to the
    stored actions of the `shifted` transitions (default: the excluded ones); its weights after
    the update."""
    shifted = excluded if shifted is None else shifted
    alg = _algorithm(LeanPPO, excludes=True)
    data = _data(7)
    with torch.inference_mode():
        for t, (obs, rewards, dones) in enumerate(data[:-1]):
            alg.act(obs)
            alg.storage.actions[t][shifted[t]] += actions_offset
            alg.record(rewards, dones, excluded[t])
        alg.compute_returns(rsl_ppo._obs(data[-1][0]))
    torch.manual_seed(1)  # the update's permutation
    alg.update()
    return _weights(alg)


def test_excluded_transitions_leave_the_update_alone_and_none_excluded_is_plain_ppo():
    """Robust PLR's exploratory levels: what an excluded transition stores (here its action)
    changes nothing in the update; with nothing excluded the update is `LeanPPO`'s own."""
    excluded = torch.rand((T, N), generator=torch.Generator().manual_seed(3)) < 0.4
    assert _same(_excluding_update(0.0, excluded), _excluding_update(5.0, excluded))
    kept = ~excluded  # the same change to kept transitions does change it
    assert not _same(_excluding_update(0.0, excluded), _excluding_update(5.0, excluded, kept))
    none = torch.zeros((T, N), dtype=torch.bool)
    plain = _algorithm(LeanPPO)
    _rollout(plain, _data(7), lean=True)
    torch.manual_seed(1)
    plain.update()
    assert _same(_excluding_update(0.0, none), _weights(plain))
    everything = torch.ones((T, N), dtype=torch.bool)  # nothing kept: no gradient step
    assert _same(_excluding_update(0.0, everything), _excluding_update(5.0, everything))
