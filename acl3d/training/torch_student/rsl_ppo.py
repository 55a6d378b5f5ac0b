"""rsl_rl's PPO as acl3d's torch-native student: rollouts, updates and state stay on one device.

rsl_rl (`pip install acl3d[train]`) provides the algorithm (`rsl_rl.algorithms.PPO`), the
actor-critic MLPs with empirical observation normalisation (`rsl_rl.models.MLPModel`) and the
rollout storage. This module adds what acl3d's runs need around them: clipping actions to the
action bounds, bootstrapping the value of an episode cut by the time limit from its final
observation, reward normalisation, the complete state for exact resumes, and the policy file a
run saves (`final_model.zip`: the actor's weights and normaliser, and what built it).
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import torch

from acl3d.extras import optional_dependency
from acl3d.training.torch_student.lean_ppo import LeanPPO
from acl3d.training.torch_student.policy_file import POLICY_MEMBERS

with optional_dependency("the rsl-ppo student"):
    from rsl_rl.models import MLPModel
    from rsl_rl.storage import RolloutStorage
    from tensordict import TensorDict

NAME = "rsl-ppo"
_GROUPS = {"actor": ["policy"], "critic": ["policy"]}
# the preset's keys that rsl_rl's PPO takes (the rest build the networks and the rollout)
ALGORITHM_KEYS = ("num_learning_epochs", "num_mini_batches", "clip_param", "gamma", "lam",
                  "value_loss_coef", "entropy_coef", "learning_rate", "max_grad_norm",
                  "use_clipped_value_loss", "schedule", "desired_kl")  # fmt: skip


def algorithm_settings(params: dict) -> dict:
    """The keyword arguments of rsl_rl's `PPO` in a preset's `params`."""
    return {k: params[k] for k in ALGORITHM_KEYS}


def _models(spec: dict, num_envs: int, device) -> tuple[MLPModel, MLPModel, TensorDict]:
    """The actor and critic of `spec` (sizes, hidden dims, activation, initial noise)."""
    obs = _obs(torch.zeros(num_envs, spec["observation_size"], device=device))
    layers = dict(hidden_dims=list(spec["hidden_dims"]), activation=spec["activation"])
    dist = {
        "class_name": "GaussianDistribution",
        "init_std": spec["init_noise_std"],
        # a floor under the action noise; policy files saved before it existed have none
        "std_range": (spec.get("min_noise_std", 0.0), float("inf")),
    }
    actor = MLPModel(
        obs, _GROUPS, "actor", spec["action_size"], **layers, obs_normalization=True,
        distribution_cfg=dist,
    )  # fmt: skip
    critic = MLPModel(obs, _GROUPS, "critic", 1, **layers, obs_normalization=True)
    return actor.to(device), critic.to(device), obs


def _actor(spec: dict, weights: dict, device) -> MLPModel:
    """An actor of `spec` with `weights`, built without a draw from the global generator (its
    initial weights, overwritten anyway, would take draws that belong to training)."""
    with torch.random.fork_rng(devices=[]):  # the models are initialised on the CPU
        actor = _models(spec, 1, device)[0]
    actor.load_state_dict(weights)
    return actor


def _obs(tensor: torch.Tensor) -> TensorDict:
    return TensorDict({"policy": tensor}, batch_size=[tensor.shape[0]], device=tensor.device)


class RewardNormaliser:
    """Divides rewards by the running std of each world's discounted return (VecNormalize's
    scheme, on tensors), clipped to [-10, 10]."""

    def __init__(self, num_envs: int, gamma: float, device):
        self.gamma = gamma
        self.returns = torch.zeros(num_envs, dtype=torch.float64, device=device)
        self.mean = torch.zeros((), dtype=torch.float64, device=device)
        self.var = torch.ones((), dtype=torch.float64, device=device)
        self.count = torch.full((), 1e-4, dtype=torch.float64, device=device)

    def __call__(self, rewards: torch.Tensor, dones: torch.Tensor) -> torch.Tensor:
        self.returns = self.returns * self.gamma + rewards
        batch_mean, batch_var, n = (
            self.returns.mean(),
            self.returns.var(unbiased=False),
            rewards.numel(),
        )
        delta, total = batch_mean - self.mean, self.count + n
        m2 = self.var * self.count + batch_var * n + delta**2 * self.count * n / total
        self.mean, self.var, self.count = self.mean + delta * n / total, m2 / total, total
        self.returns.masked_fill_(dones, 0.0)  # a mask, not indexing: no host sync on a GPU
        return (rewards / torch.sqrt(self.var + 1e-8)).clamp(-10.0, 10.0).float()

    def state_dict(self) -> dict:
        return {k: getattr(self, k).clone() for k in ("returns", "mean", "var", "count")}

    def load_state_dict(self, state: dict) -> None:
        for key, value in state.items():
            setattr(self, key, value.to(self.returns.device))


class RslPPO:
    """The student of one run: `act` / `record` every step, `update` after each rollout."""

    def __init__(self, params: dict, observation_size: int, action_size: int, num_envs: int,
                 device, action_low: torch.Tensor, action_high: torch.Tensor,
                 exclude_exploratory: bool = False):  # fmt: skip
        self.params, self.device = dict(params), torch.device(device)
        self.exclude_exploratory = bool(exclude_exploratory)
        self.spec = {
            "student": NAME,
            "observation_size": int(observation_size),
            "action_size": int(action_size),
            **{
                k: params[k]
                for k in ("hidden_dims", "activation", "init_noise_std", "min_noise_std")
            },
        }
        self.num_envs = int(num_envs)
        self.reinitialise()
        self.steps_per_env = int(params["num_steps_per_env"])
        shape = (self.steps_per_env, self.num_envs)  # per step of a rollout: cut episodes
        self._cut = torch.zeros(shape, dtype=torch.bool, device=self.device)
        self._bootstrap = torch.zeros(shape, device=self.device)  # gamma x V(final obs)
        self._bootstrapped = [False] * self.steps_per_env
        self.bootstraps_every_step = self.device.type != "cpu"  # no wait for the GPU's answer
        self.low, self.high = action_low.to(self.device), action_high.to(self.device)
        self.rewards = (
            RewardNormaliser(num_envs, params["gamma"], self.device)
            if params["normalize_rewards"]
            else None
        )

    def reinitialise(self) -> None:
        """Fresh networks (their observation normalisers too), optimiser, learning rate and
        rollout storage, drawn from the global generator: a new student, or a forgetting one
        (`reset_student_every`). The reward normaliser, the env side's statistics, stays."""
        params = self.params
        actor, critic, obs = _models(self.spec, self.num_envs, self.device)
        storage = RolloutStorage(
            "rl", self.num_envs, params["num_steps_per_env"], obs, [self.spec["action_size"]],
            str(self.device),
        )  # fmt: skip
        self.alg = LeanPPO(
            actor, critic, storage, device=str(self.device), excludes=self.exclude_exploratory,
            **algorithm_settings(params),
        )  # fmt: skip
        self.alg.train_mode()

    # ------------------------------------------------------------------ the rollout
    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """Sampled actions for the env (clipped to the action bounds; the storage keeps the
        sampled ones, as SB3's PPO does)."""
        return self.alg.act(obs).clamp(self.low, self.high)

    def record(
        self, rewards, terminated, truncated, final_obs: torch.Tensor, excluded=None
    ) -> None:
        """One step's outcome, its rewards as the env gave them: `update` normalises the
        rollout's rewards and bootstraps the episodes the time limit cut, step by step, with
        the operations a step would run (right after the physics, each small tensor operation
        costs about twice as much). A cut episode is bootstrapped with the value of its final
        observation (the critic runs on every world and the mask picks: asking which worlds
        were cut would wait for the GPU at every step; on the CPU it runs only when one was).
        `excluded`: the worlds whose step the update leaves out (with `exclude_exploratory`)."""
        self.alg.record(rewards, terminated | truncated, excluded)
        step = self.alg.storage.step - 1
        cut = truncated & ~terminated
        self._bootstrapped[step] = self.bootstraps_every_step or bool(cut.any())
        if self._bootstrapped[step]:
            self._cut[step].copy_(cut)
            self._bootstrap[step].copy_(self.alg.gamma * self.alg.value(final_obs))

    def update(self, last_obs: torch.Tensor) -> dict[str, float]:
        self._finish_rewards()
        self.alg.compute_returns(_obs(last_obs))
        return self.alg.update()

    def _finish_rewards(self) -> None:
        """The stored rewards normalised, then the cut episodes' bootstraps added, in step
        order."""
        st = self.alg.storage
        with torch.no_grad():
            for step in range(st.step):
                rewards = st.rewards[step].view(-1)
                if self.rewards is not None:
                    rewards = self.rewards(rewards, st.dones[step].view(-1).bool())
                if self._bootstrapped[step]:
                    bootstrapped = rewards + self._bootstrap[step]
                    rewards = torch.where(self._cut[step], bootstrapped, rewards)
                st.rewards[step].copy_(rewards.view(-1, 1))

    @property
    def learning_rate(self) -> float:
        return float(self.alg.learning_rate)

    @property
    def action_std(self) -> float:
        """The mean std the actions are sampled with (the learned one, at least its floor)."""
        return float(self.alg.action_std().detach().mean())

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        """V(s) of raw observations (the critic normalises them itself)."""
        with torch.inference_mode():
            return self.alg.value(obs.to(self.device))

    def snapshot(self, weights: dict | None = None) -> PolicySnapshot:
        """The actor as it is now (or with `weights`, a snapshot's `state_dict`), frozen: what
        an evaluation plays while training goes on."""
        weights = self.alg.actor.state_dict() if weights is None else weights
        return PolicySnapshot(
            self.spec, _actor(self.spec, weights, self.device), self.low, self.high
        )

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict:
        """Weights, normalisers, optimiser, adaptive learning rate and reward statistics."""
        state = self.alg.save()
        state["learning_rate"] = self.alg.learning_rate
        state["rewards"] = None if self.rewards is None else self.rewards.state_dict()
        return state

    def load_state_dict(self, state: dict) -> None:
        self.alg.load(state, None, strict=True)
        self.alg.learning_rate = float(state["learning_rate"])
        if self.rewards is not None:
            self.rewards.load_state_dict(state["rewards"])

    def save_policy(self, path) -> None:
        """The policy file (`POLICY_MEMBERS`): what `load_policy` needs to act."""
        buffer = io.BytesIO()
        weights = self.alg.actor.state_dict()  # views of the optimiser's flat copy: cloned
        torch.save({k: v.detach().to("cpu", copy=True) for k, v in weights.items()}, buffer)
        with zipfile.ZipFile(path, "w") as z:
            z.writestr(POLICY_MEMBERS[0], json.dumps(self.spec))
            z.writestr(POLICY_MEMBERS[1], buffer.getvalue())


class PolicySnapshot:
    """A copy of the actor (weights and observation normaliser) at one step of training.

    Evaluations play snapshots, so several steps' policies can be evaluated side by side in one
    pass, after the training that followed them. Sampled actions come from the caller's
    generator: `torch.normal` with the actor's mean and std, the draws `Normal.sample` makes from
    the global generator, which an evaluation must leave to training.
    """

    def __init__(self, spec: dict, actor: MLPModel, low, high):
        self.spec, self.actor = dict(spec), actor.eval()
        self.device = next(actor.parameters()).device
        self.low = torch.as_tensor(low, device=self.device)
        self.high = torch.as_tensor(high, device=self.device)
        self.observation_size = int(self.spec["observation_size"])
        self.action_size = int(self.spec["action_size"])

    def __call__(self, obs: torch.Tensor, generator: torch.Generator | None = None):
        """Actions for (N, obs) observations: the mean (generator None) or sampled, clipped to
        the action bounds."""
        with torch.inference_mode():
            mean = self.actor(_obs(obs.to(self.device, torch.float32)))
            if generator is not None:
                self.actor.distribution.update(mean)
                std = self.actor.distribution.std.expand_as(mean)
                mean = torch.normal(mean, std, generator=generator)
        return mean.clamp(self.low, self.high)

    def state_dict(self) -> dict:
        """The weights on the CPU (a checkpoint keeps the snapshots waiting for evaluation)."""
        return {k: v.cpu() for k, v in self.actor.state_dict().items()}


class SavedPolicy:
    """A saved rsl-ppo policy on the CPU: (N, obs) numpy -> (N, act) actions in [-1, 1]."""

    def __init__(self, path):
        path = Path(path)
        with zipfile.ZipFile(path) as z:
            spec = json.loads(z.read(POLICY_MEMBERS[0]))
            weights = torch.load(io.BytesIO(z.read(POLICY_MEMBERS[1])), weights_only=True)
        self.snapshot = PolicySnapshot(spec, _actor(spec, weights, "cpu"), -1.0, 1.0)
        self.spec = self.snapshot.spec
        self.observation_size = self.snapshot.observation_size
        self.action_size = self.snapshot.action_size

    def __call__(self, obs, deterministic: bool = True):
        if deterministic:
            return self.snapshot(torch.as_tensor(obs)).numpy()
        with torch.inference_mode():  # sampled from the global generator, as any torch policy
            x = _obs(torch.as_tensor(obs, dtype=torch.float32))
            return self.snapshot.actor(x, stochastic_output=True).clamp(-1.0, 1.0).numpy()
