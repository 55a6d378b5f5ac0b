"""CleanRL-style PPO in one file of plain PyTorch, on acl3d's batched vector env, with an ALP-GMM
curriculum choosing each sub-env's task at its reset.

    python scripts/examples/cleanrl_ppo.py --total-steps 700000            # Stump Tracks
    python scripts/examples/cleanrl_ppo.py --flat --teacher random         # the flat track

Needs `pip install "acl3d[train]"` (torch; the teacher and env come with the core).

The settings are `acl3d train --student ppo --preset fast --n-envs 16`'s (SB3's PPO): 64-64 tanh
actor and critic, 256 steps x 16 envs per rollout, 10 epochs of minibatches of 512, Adam 3e-4
(eps 1e-5), clip 0.2, gradients clipped at 0.5, observations and rewards normalised and clipped
at 10 as SB3's VecNormalize does (`VecNormalize` below), and episodes cut by the time limit
bootstrapped from the value of their last observation, as SB3 does.

Why not Gymnasium's `NormalizeReward`: its discounted return restarts at the step that ends an
episode by termination, so a fall's -100 carries into the next episode's return (and a time
limit's return is never restarted). Under random actions on Stump Tracks that makes the return's
standard deviation 3.5x SB3's and every normalised reward 3.5x smaller (a fall: -3, not -10);
the loop then needed 1.5-1.7x the steps of `acl3d train` to learn to walk the flat track, and
about the same with SB3's normalisation (docs/own-loop.md).

Gymnasium's NEXT_STEP autoreset: the step after an episode ends only resets that sub-env (reward
0, its action ignored); that transition is left out of the updates. Every finished episode is
written to OUT/episodes.csv with the layout of `acl3d train`'s (step, worker, return, length,
success, truncated, task), so the two learning curves compare directly.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from gymnasium.wrappers import vector as vw
from gymnasium.wrappers.utils import RunningMeanStd
from torch import nn
from torch.distributions import Normal

import acl3d  # noqa: F401  (registers the environments)
from acl3d.envs.batched_vector import BatchedVectorEnv
from acl3d.teachers import make as make_teacher


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="acl3d/StumpTracks-v0")
    p.add_argument("--teacher", default="alp-gmm")
    p.add_argument("--flat", action="store_true", help="stump_height 0 only (the flat track)")
    p.add_argument("--total-steps", type=int, default=700_000)
    p.add_argument("--num-envs", type=int, default=16)
    p.add_argument("--num-steps", type=int, default=256, help="steps per env per rollout")
    p.add_argument("--minibatch-size", type=int, default=512)
    p.add_argument("--epochs", type=int, default=10)
    p.add_argument("--lr", type=float, default=3e-4)
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--gae-lambda", type=float, default=0.95)
    p.add_argument("--clip", type=float, default=0.2)
    p.add_argument("--vf-coef", type=float, default=0.5)
    p.add_argument("--max-grad-norm", type=float, default=0.5)
    p.add_argument("--max-episode-steps", type=int, default=None, help="default: the env's")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--torch-threads", type=int, default=1)
    p.add_argument("--out", default="runs/cleanrl_ppo")
    p.add_argument("--quiet", action="store_true")
    return p.parse_args(argv)


def layer(n_in: int, n_out: int, gain: float) -> nn.Linear:
    """Orthogonal weights, zero biases (SB3's and CleanRL's initialisation)."""
    lin = nn.Linear(n_in, n_out)
    nn.init.orthogonal_(lin.weight, gain)
    nn.init.zeros_(lin.bias)
    return lin


class Agent(nn.Module):
    """Separate 64-64 tanh actor and critic; a state-independent log std (SB3's MlpPolicy)."""

    def __init__(self, obs_size: int, act_size: int):
        super().__init__()

        def mlp(out: int, gain: float) -> nn.Sequential:
            hidden = np.sqrt(2)
            return nn.Sequential(
                layer(obs_size, 64, hidden), nn.Tanh(), layer(64, 64, hidden), nn.Tanh(),
                layer(64, out, gain),
            )  # fmt: skip

        self.critic, self.actor_mean = mlp(1, 1.0), mlp(act_size, 0.01)
        self.log_std = nn.Parameter(torch.zeros(act_size))

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        return self.critic(obs).squeeze(-1)

    def act(self, obs: torch.Tensor, action: torch.Tensor | None = None):
        """(action, log prob, entropy, value); samples an action when none is given."""
        dist = Normal(self.actor_mean(obs), self.log_std.exp())
        if action is None:
            action = dist.sample()
        return action, dist.log_prob(action).sum(-1), dist.entropy().sum(-1), self.value(obs)


class VecNormalize(gym.vector.VectorWrapper):
    """SB3's VecNormalize on a NEXT_STEP vector env: observations and rewards scaled by running
    statistics and clipped at `clip`; the reward by the standard deviation of a discounted return
    that restarts after every episode end (termination or time limit). As SB3 never sees an
    episode's final observation or NEXT_STEP's reset step, neither enters the statistics."""

    def __init__(self, env, gamma: float, clip: float = 10.0, epsilon: float = 1e-8):
        super().__init__(env)
        self.gamma, self.clip, self.epsilon = gamma, clip, epsilon
        self.obs_rms = RunningMeanStd(shape=env.single_observation_space.shape)
        self.ret_rms = RunningMeanStd(shape=())
        self.returns = np.zeros(self.num_envs)
        self.resetting = np.zeros(self.num_envs, dtype=bool)  # this step only resets these

    def reset(self, **kwargs):
        obs, infos = self.env.reset(**kwargs)
        self.returns[:], self.resetting[:] = 0.0, False
        self.obs_rms.update(obs)
        return self.scale(obs), infos

    def step(self, actions):
        obs, rewards, terminated, truncated, infos = self.env.step(actions)
        ended, live = terminated | truncated, ~self.resetting
        if not ended.all():
            self.obs_rms.update(obs[~ended])  # a final observation is normalised, not counted
        if live.any():
            self.returns[live] = self.returns[live] * self.gamma + rewards[live]
            self.ret_rms.update(self.returns[live])
        self.returns[ended], self.resetting = 0.0, ended
        rewards = np.clip(rewards / np.sqrt(self.ret_rms.var + self.epsilon), -self.clip, self.clip)
        return self.scale(obs), rewards, terminated, truncated, infos

    def scale(self, obs: np.ndarray) -> np.ndarray:
        z = (obs - self.obs_rms.mean) / np.sqrt(self.obs_rms.var + self.epsilon)
        return np.clip(z, -self.clip, self.clip).astype(np.float32)


def make_env(args) -> tuple[gym.vector.VectorEnv, object]:
    """The batched env with the teacher choosing each sub-env's task at its reset, actions
    clipped to the action space and SB3's normalisation (as `acl3d train` runs PPO)."""
    kwargs = {} if args.max_episode_steps is None else {"max_episode_steps": args.max_episode_steps}
    probe = BatchedVectorEnv(args.env, 1, threads=1, **kwargs)
    space = probe.task_space.with_bounds(stump_height=(0.0, 0.0)) if args.flat else probe.task_space
    probe.close()
    teacher = make_teacher(args.teacher, space.gym_space, seed=args.seed)
    envs = BatchedVectorEnv(args.env, args.num_envs, teacher=teacher, **kwargs)
    envs = VecNormalize(vw.ClipAction(envs), gamma=args.gamma)
    return envs, teacher


def train(args) -> dict:
    """Run PPO; returns {"steps", "seconds", "steps_per_s", "episodes"}."""
    torch.set_num_threads(args.torch_threads)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    envs, teacher = make_env(args)
    n, t_max = args.num_envs, args.num_steps
    obs_size = envs.single_observation_space.shape[0]
    act_size = envs.single_action_space.shape[0]
    agent = Agent(obs_size, act_size)
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.lr, eps=1e-5)

    obs_buf = torch.zeros((t_max, n, obs_size))
    act_buf = torch.zeros((t_max, n, act_size))
    logp_buf, val_buf, rew_buf = (torch.zeros((t_max, n)) for _ in range(3))
    term_buf, end_buf, valid_buf = (torch.zeros((t_max, n), dtype=torch.bool) for _ in range(3))

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    names = envs.unwrapped.task_space.flat_names()
    log = open(out / "episodes.csv", "w", newline="")
    writer = csv.writer(log)
    writer.writerow(["step", "worker", "return", "length", "success", "truncated", *names])

    obs, _ = envs.reset(seed=args.seed)
    obs = torch.as_tensor(obs, dtype=torch.float32)
    resetting = torch.zeros(n, dtype=torch.bool)  # this step only resets these sub-envs
    steps, episodes, start = 0, 0, time.perf_counter()
    while steps < args.total_steps:
        for t in range(t_max):
            with torch.no_grad():
                action, logp, _, value = agent.act(obs)
            obs_buf[t], act_buf[t], logp_buf[t], val_buf[t] = obs, action, logp, value
            valid_buf[t] = ~resetting
            next_obs, reward, terminated, truncated, infos = envs.step(action.numpy())
            steps += n
            rew_buf[t] = torch.as_tensor(reward, dtype=torch.float32)
            term_buf[t] = torch.as_tensor(terminated)
            end_buf[t] = torch.as_tensor(terminated | truncated)
            for i in np.flatnonzero(infos.get("_curriculum", ())):
                ep = infos["curriculum"][i]
                writer.writerow(
                    [steps, i, f"{ep['return']:.6g}", ep["length"], int(ep["success"]),
                     int(ep["truncated"]), *(f"{v:.6g}" for v in ep["task"])]
                )  # fmt: skip
                episodes += 1
            obs = torch.as_tensor(next_obs, dtype=torch.float32)
            resetting = end_buf[t].clone()

        # GAE. The transition after an episode's end is a reset: left out, and its value (of the
        # episode's last observation) bootstraps a time-limit cut.
        with torch.no_grad():
            next_value = agent.value(obs)
        adv = torch.zeros((t_max, n))
        last = torch.zeros(n)
        for t in reversed(range(t_max)):
            following = next_value if t == t_max - 1 else val_buf[t + 1]
            delta = rew_buf[t] + args.gamma * following * ~term_buf[t] - val_buf[t]
            carry = args.gamma * args.gae_lambda * last * ~end_buf[t]
            last = torch.where(valid_buf[t], delta + carry, torch.zeros(n))
            adv[t] = last
        returns = adv + val_buf

        keep = valid_buf.reshape(-1)
        b_obs, b_act = obs_buf.reshape(-1, obs_size)[keep], act_buf.reshape(-1, act_size)[keep]
        b_logp, b_adv = logp_buf.reshape(-1)[keep], adv.reshape(-1)[keep]
        b_ret = returns.reshape(-1)[keep]
        size = len(b_obs)
        for _ in range(args.epochs):
            order = torch.as_tensor(rng.permutation(size))
            for lo in range(0, size, args.minibatch_size):
                mb = order[lo : lo + args.minibatch_size]
                _, logp, _, value = agent.act(b_obs[mb], b_act[mb])
                ratio = (logp - b_logp[mb]).exp()
                mb_adv = b_adv[mb]
                mb_adv = (mb_adv - mb_adv.mean()) / (mb_adv.std() + 1e-8)
                clipped = ratio.clamp(1 - args.clip, 1 + args.clip)
                policy_loss = -torch.min(mb_adv * ratio, mb_adv * clipped).mean()
                value_loss = ((b_ret[mb] - value) ** 2).mean()
                loss = policy_loss + args.vf_coef * value_loss
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
        log.flush()
        if not args.quiet:
            rate = steps / (time.perf_counter() - start)
            print(f"steps {steps}  episodes {episodes}  {rate:.0f} steps/s", flush=True)
    seconds = time.perf_counter() - start
    log.close()
    envs.close()
    torch.save(agent.state_dict(), out / "agent.pt")
    return {
        "steps": steps,
        "seconds": seconds,
        "steps_per_s": steps / seconds,
        "episodes": episodes,
    }


if __name__ == "__main__":
    print(train(parse_args()))
