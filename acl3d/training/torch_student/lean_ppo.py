"""rsl_rl's PPO in fewer, larger tensor operations: the same arithmetic, bit for bit.

On a 2-core CPU the update of `fast`'s [64, 64] networks is about half of a run's wall time, and
a third of the update was per-call overhead rather than arithmetic: Adam stepped thirteen small
parameter tensors (about 80 operations a step), every minibatch indexed eight rollout tensors by
the permutation and normalised its observations again, and every acting step built TensorDicts.
`LeanPPO` keeps rsl_rl's models, storage, returns and losses, and changes only how they are
computed:

* Adam steps one flat copy of every parameter (a view of each), whose elementwise arithmetic is
  the multi-tensor step's; each parameter's gradient is a view of the flat gradient, which the
  backward passes fill (zeroed first: 0 + g is g) and the clippings scale in place.
* An update gathers the rollout once in the order of rsl_rl's permutation (drawn once for all
  epochs) and normalises the observations once (the normalisers change only after the update),
  so a minibatch is a slice.
* `act` and `record` run the networks on tensors and write the storage directly; `act` runs
  only the actor, layer by layer through each module's `forward` (a module call's hook checks
  cost as much as a 64-row layer), and samples the actions with `torch.normal`, as the Gaussian
  distribution's `sample` does, without building the distribution. The rollout's values (the critic on each step's observations, as rsl_rl's
  `act` computes them: a linear layer's bits can depend on its batch size) and the actions'
  log-probabilities (elementwise: in one pass) are computed before its returns. On two cores
  every small tensor operation right after a physics step is about twice as slow as in a run
  of them, so acting does only what the next action needs.
* On the CPU the critic's forward and backward pass of a minibatch run on a second thread while
  the actor's run on the caller's (torch releases the GIL in its kernels; the networks share no
  parameter): the update takes about 0.7x the time on two cores, and the physics' threads are
  idle then.

Checkpoints keep rsl_rl's layout (an optimiser state per parameter), so either class resumes the
other's. `tests/test_lean_ppo.py` checks the bits against `rsl_rl.algorithms.PPO`.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import torch
from torch import nn
from torch.distributions import Normal

from acl3d.extras import optional_dependency

with optional_dependency("the rsl-ppo student"):
    from rsl_rl.algorithms import PPO
    from rsl_rl.modules.distribution import GaussianDistribution


class LeanPPO(PPO):
    """`rsl_rl.algorithms.PPO` for feedforward Gaussian actors and critics, without RND,
    symmetry, several GPUs, mixed precision or per-minibatch advantage normalisation.

    `critic_thread` (default: on the CPU) runs the critic's share of each minibatch on a second
    thread beside the actor's (on a GPU the kernels already run beside the Python). `excludes`:
    `record` marks transitions left out of the update (Robust PLR's exploratory levels, as SB3
    PPO's `ExcludingRolloutBuffer` does): the minibatches hold the kept ones of rsl_rl's
    permutation, at its minibatch size; they still bound their episode's advantages."""

    def __init__(
        self, actor, critic, storage, critic_thread: bool | None = None, excludes: bool = False,
        **settings,
    ):  # fmt: skip
        super().__init__(actor, critic, storage, **settings)
        self.excludes = bool(excludes)
        steps = (storage.num_transitions_per_env, storage.num_envs)
        self.excluded = torch.zeros(steps, dtype=torch.bool, device=storage.device)
        self.critic_thread = (
            torch.device(self.device).type == "cpu" if critic_thread is None else critic_thread
        )
        if self.rnd or self.symmetry or self.is_multi_gpu or self.use_mixed_precision:
            raise ValueError("LeanPPO covers plain PPO: no RND, symmetry, multi-GPU or AMP")
        if self.normalize_advantage_per_mini_batch or actor.is_recurrent or critic.is_recurrent:
            raise ValueError("LeanPPO covers feedforward models with whole-batch advantages")
        distribution = actor.distribution
        if type(distribution) is not GaussianDistribution or distribution.std_type != "scalar":
            raise ValueError("LeanPPO covers Gaussian actors with a state-independent scalar std")
        # the networks' modules, called through `forward`: the same arithmetic without hooks
        self.actor_layers = list(actor.mlp)
        self.critic_layers = list(critic.mlp)
        self.actor_params = list(self.actor.parameters())
        self.critic_params = list(self.critic.parameters())
        self.params = self.actor_params + self.critic_params
        self.flat = torch.cat([p.detach().reshape(-1) for p in self.params]).requires_grad_()
        for p, view in zip(self.params, self._split(self.flat.detach())):
            p.data = view
        self.flat.grad = torch.zeros_like(self.flat)
        group = self.optimizer.defaults
        self.optimizer = torch.optim.Adam(
            [self.flat], lr=group["lr"], betas=group["betas"], eps=group["eps"],
            weight_decay=group["weight_decay"], foreach=False,
        )  # fmt: skip
        if storage.distribution_params is None:  # rsl_rl allocates them at the first step
            shape = (storage.num_transitions_per_env, storage.num_envs, *storage.actions_shape)
            storage.distribution_params = tuple(
                torch.zeros(shape, device=storage.device) for _ in range(2)
            )
        self.observations = storage.observations["policy"]

    def _split(self, flat: torch.Tensor) -> list[torch.Tensor]:
        """`flat` cut into views shaped as the parameters."""
        sizes = [p.numel() for p in self.params]
        return [v.view_as(p) for v, p in zip(flat.split(sizes), self.params)]

    # ------------------------------------------------------------------ the rollout
    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """Sampled actions for (N, obs) observations; the step is stored as rsl_rl stores it."""
        mean = _forward(self.actor_layers, self.actor.obs_normalizer.forward(obs))
        std = self.action_std().expand_as(mean)
        actions = torch.normal(mean, std)  # `Normal(mean, std).sample()`: the same draws
        st, i = self.storage, self.storage.step
        self.observations[i].copy_(obs)
        st.actions[i].copy_(actions)
        st.distribution_params[0][i].copy_(mean)
        st.distribution_params[1][i].copy_(std)
        return actions

    def action_std(self) -> torch.Tensor:
        """The Gaussian's std, as `GaussianDistribution.update` computes it (scalar type)."""
        distribution = self.actor.distribution
        return distribution.std_param.clamp(*distribution.std_range)

    def compute_returns(self, obs) -> None:
        """rsl_rl's returns and advantages, after the rollout's values and log-probabilities
        (which rsl_rl computes at each `act`)."""
        st = self.storage
        with torch.no_grad():
            for values, observed in zip(st.values, self.observations):
                values.copy_(self._critic(observed))
            mean, std = st.distribution_params
            st.actions_log_prob.copy_(Normal(mean, std).log_prob(st.actions).sum(-1, keepdim=True))
        super().compute_returns(obs)

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        """V(s) of (N, obs) observations, (N,)."""
        return self._critic(obs).squeeze(-1)

    def _critic(self, obs: torch.Tensor) -> torch.Tensor:
        return _forward(self.critic_layers, self.critic.obs_normalizer.forward(obs))

    def record(self, rewards: torch.Tensor, dones: torch.Tensor, excluded=None) -> None:
        """The outcome of the step `act` stored (`excluded`: (N,) bools, with `excludes`)."""
        st = self.storage
        if st.step >= st.num_transitions_per_env:
            raise OverflowError("the rollout is full: update() before acting again")
        st.rewards[st.step].copy_(rewards.view(-1, 1))
        st.dones[st.step].copy_(dones.view(-1, 1))
        if self.excludes:
            self.excluded[st.step].copy_(excluded)
        st.step += 1

    # ------------------------------------------------------------------ the update
    def update(self) -> dict[str, float]:
        st, batches, epochs = self.storage, self.num_mini_batches, self.num_learning_epochs
        size = st.num_envs * st.num_transitions_per_env // batches
        order = torch.randperm(batches * size, device=st.device)
        if self.excludes:  # the kept transitions, in the permutation's order
            order = order[~self.excluded.flatten()[order]]
            self.excluded.zero_()
        flat = self.observations.flatten(0, 1)[order]
        obs_actor, obs_critic = self.actor.obs_normalizer(flat), self.critic.obs_normalizer(flat)
        actions, values, returns, old_log_prob, advantages, old_mean, old_std = (
            t.flatten(0, 1)[order]
            for t in (st.actions, st.values, st.returns, st.actions_log_prob, st.advantages,
                      *st.distribution_params)
        )  # fmt: skip
        old_log_prob, advantages = old_log_prob.squeeze(-1), advantages.squeeze(-1)
        distribution, threads = self.actor.distribution, torch.get_num_threads()
        for p, view in zip(self.params, self._split(self.flat.grad)):
            p.grad = view  # the backward passes accumulate into the zeroed views
        totals = torch.zeros(3, dtype=torch.float64, device=st.device)
        steps = epochs * -(-len(order) // size)  # gradient steps (none if nothing is kept)
        for _ in range(epochs if steps else 0):
            for start in range(0, len(order), size):
                b = slice(start, start + size)
                self.flat.grad.zero_()
                critic = (obs_critic[b], values[b], returns[b])
                if self.critic_thread:
                    critic_loss = _critic_thread().submit(self._critic_step, *critic, threads)
                distribution.update(_forward(self.actor_layers, obs_actor[b]))
                distribution.sample()  # rsl_rl's forward draws one; the generator must agree
                if self.desired_kl is not None and self.schedule == "adaptive":
                    self._adapt_learning_rate(old_mean[b], old_std[b])
                log_prob = distribution.log_prob(actions[b])
                with torch.set_grad_enabled(bool(self.entropy_coef)):  # 0: logged only
                    entropy = distribution.entropy.mean()
                ratio = torch.exp(log_prob - old_log_prob[b])
                surrogate = -advantages[b] * ratio
                clipped = -advantages[b] * torch.clamp(
                    ratio, 1.0 - self.clip_param, 1.0 + self.clip_param
                )
                surrogate_loss = torch.max(surrogate, clipped).mean()
                entropy_term = self.entropy_coef * entropy if self.entropy_coef else 0.0
                (surrogate_loss - entropy_term).backward()  # 0: the surrogate's gradient alone
                nn.utils.clip_grad_norm_(self.actor_params, self.max_grad_norm)
                value_loss = (
                    critic_loss.result() if self.critic_thread else self._critic_step(*critic)
                )
                self.optimizer.step()
                totals += torch.stack([value_loss, surrogate_loss, entropy]).detach().double()
        observed = st.observations.flatten(0, 1)
        self.actor.update_normalization(observed)
        self.critic.update_normalization(observed)
        st.clear()
        value, surrogate, entropy = (totals / max(steps, 1)).tolist()
        return {"value": value, "surrogate": surrogate, "entropy": entropy}

    def _critic_step(self, obs, values, returns, threads: int | None = None) -> torch.Tensor:
        """The critic's share of a minibatch: its value loss, backward pass and clipping. The
        networks share no parameter, so this backward pass and the actor's give the gradients
        of rsl_rl's summed loss, bit for bit. On the worker thread, `threads` is the caller's
        torch thread count (a fresh thread starts at the core count)."""
        if threads is not None and torch.get_num_threads() != threads:
            torch.set_num_threads(threads)
        value = _forward(self.critic_layers, obs)
        if self.use_clipped_value_loss:
            clipped = values + (value - values).clamp(-self.clip_param, self.clip_param)
            loss = torch.max((value - returns).pow(2), (clipped - returns).pow(2)).mean()
        else:
            loss = (returns - value).pow(2).mean()
        (self.value_loss_coef * loss).backward()
        nn.utils.clip_grad_norm_(self.critic_params, self.max_grad_norm)
        return loss

    def _adapt_learning_rate(self, old_mean: torch.Tensor, old_std: torch.Tensor) -> None:
        with torch.inference_mode():
            params = self.actor.distribution.params
            kl = torch.mean(self.actor.get_kl_divergence((old_mean, old_std), params))
            if kl > self.desired_kl * 2.0:
                self.learning_rate = max(1e-5, self.learning_rate / 1.5)
            elif kl < self.desired_kl / 2.0 and kl > 0.0:
                self.learning_rate = min(1e-2, self.learning_rate * 1.5)
            self.optimizer.param_groups[0]["lr"] = self.learning_rate

    # ------------------------------------------------------------------ rsl_rl's layout
    def save(self) -> dict:
        state = super().save()
        state["optimizer_state_dict"] = self._per_parameter(state["optimizer_state_dict"])
        return state

    def load(self, loaded_dict: dict, load_cfg: dict | None, strict: bool) -> bool:
        loaded = dict(loaded_dict)
        loaded["optimizer_state_dict"] = self._flat_state(loaded["optimizer_state_dict"])
        return super().load(loaded, load_cfg, strict)

    def _per_parameter(self, flat_state: dict) -> dict:
        """The flat optimiser state as rsl_rl's Adam keeps it, one entry per parameter."""
        group = {**flat_state["param_groups"][0], "foreach": True}
        group["params"] = list(range(len(self.params)))
        state = {}
        if 0 in flat_state["state"]:
            moments = flat_state["state"][0]
            views = {k: self._split(moments[k]) for k in ("exp_avg", "exp_avg_sq")}
            for i in group["params"]:
                state[i] = {"step": moments["step"].clone(),
                            **{k: views[k][i].clone() for k in views}}  # fmt: skip
        return {"state": state, "param_groups": [group]}

    def _flat_state(self, state: dict) -> dict:
        """rsl_rl's per-parameter optimiser state as the flat Adam's."""
        group = {**state["param_groups"][0], "foreach": False}
        if len(group["params"]) != len(self.params):
            raise ValueError(
                f"the optimiser state holds {len(group['params'])} parameters; "
                f"these networks have {len(self.params)}"
            )
        group["params"] = [0]
        entries = [state["state"][i] for i in sorted(state["state"])]
        flat = {}
        if entries:
            flat[0] = {
                "step": entries[0]["step"].clone(),
                **{k: torch.cat([e[k].reshape(-1) for e in entries])
                   for k in ("exp_avg", "exp_avg_sq")},
            }  # fmt: skip
        return {"state": flat, "param_groups": [group]}


def _forward(layers: list[nn.Module], x: torch.Tensor) -> torch.Tensor:
    """`nn.Sequential(*layers)(x)` through each module's `forward`."""
    for layer in layers:
        x = layer.forward(x)
    return x


_CRITIC_THREAD: ThreadPoolExecutor | None = None


def _critic_thread() -> ThreadPoolExecutor:
    """The one worker thread every LeanPPO of the process shares for its critic."""
    global _CRITIC_THREAD
    if _CRITIC_THREAD is None:
        _CRITIC_THREAD = ThreadPoolExecutor(1, thread_name_prefix="acl3d-critic")
    return _CRITIC_THREAD
