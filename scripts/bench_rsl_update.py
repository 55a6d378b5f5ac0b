"""rsl-ppo's update alone: rsl_rl's `PPO.update` against `LeanPPO`'s (one thread, then the critic
on a second thread), on the same rollout from the same weights, in interleaved rounds.

    python scripts/bench_rsl_update.py                 # fast preset, 64 worlds, Stump Tracks sizes
    python scripts/bench_rsl_update.py --worlds 128 --param num_steps_per_env=64 --rounds 10
    python scripts/bench_rsl_update.py --device cuda --preset benchmark --worlds 16384 --rounds 5

Every variant updates a copy of one student (weights, optimiser state, learning rate, generator
state) on one stored rollout, so the rows must end with the same weights ("same weights" says
whether they do) and their times compare the same work. Prints the median over rounds and its
ratio to rsl_rl's; one torch thread per thread, as `acl3d train` runs. On a GPU (`--device
cuda`) the critic thread is left out (`LeanPPO` runs it on the CPU only) and each update is timed
to the end of its kernels.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time

import torch
import yaml
from rsl_rl.algorithms import PPO
from rsl_rl.storage import RolloutStorage

from acl3d.training.torch_student import presets, rsl_ppo
from acl3d.training.torch_student.lean_ppo import LeanPPO


def build(params: dict, worlds: int, obs_size: int, act_size: int, variant: str, device: str):
    torch.manual_seed(0)
    spec = {"observation_size": obs_size, "action_size": act_size,
            **{k: params[k] for k in ("hidden_dims", "activation", "init_noise_std")}}  # fmt: skip
    actor, critic, obs = rsl_ppo._models(spec, worlds, device)
    storage = RolloutStorage("rl", worlds, params["num_steps_per_env"], obs, [act_size], device)
    settings = rsl_ppo.algorithm_settings(params)
    if variant == "rsl_rl":
        alg = PPO(actor, critic, storage, device=device, **settings)
    else:
        alg = LeanPPO(actor, critic, storage, device=device, critic_thread=variant.endswith("thread"),
                      **settings)  # fmt: skip
    alg.train_mode()
    return alg


def fill(alg, worlds: int, steps: int, obs_size: int, seed: int, device: str) -> None:
    """One rollout of random observations, rewards and episode ends, acted by `alg`."""
    g = torch.Generator(device).manual_seed(seed)
    with torch.inference_mode():
        for _ in range(steps):
            obs = torch.randn(worlds, obs_size, generator=g, device=device) * 2
            rewards, dones = (
                torch.randn(worlds, generator=g, device=device),
                torch.rand(worlds, generator=g, device=device) < 0.01,
            )
            if isinstance(alg, LeanPPO):
                alg.act(obs)
                alg.record(rewards, dones)
            else:
                alg.act(rsl_ppo._obs(obs))
                alg.process_env_step(None, rewards, dones, {})
        last = torch.randn(worlds, obs_size, generator=g, device=device)
        alg.compute_returns(rsl_ppo._obs(last))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--worlds", type=int, default=64)
    p.add_argument("--preset", default="fast", choices=presets.PRESETS)
    p.add_argument("--param", action="append", default=[], metavar="K=V")
    p.add_argument("--obs", type=int, default=24, help="observation size (Stump Tracks: 24)")
    p.add_argument("--actions", type=int, default=4, help="action size (classic biped: 4)")
    p.add_argument("--rounds", type=int, default=8)
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    args = p.parse_args()
    device, cuda = args.device, args.device.startswith("cuda")
    torch.set_num_threads(1)
    overrides = {k: yaml.safe_load(v) for k, v in (kv.split("=", 1) for kv in args.param)}
    params = presets.hyperparameters(args.preset, args.worlds, overrides)
    steps = params["num_steps_per_env"]
    variants = ("rsl_rl", "lean") + (() if cuda else ("lean+critic thread",))
    students = {v: build(params, args.worlds, args.obs, args.actions, v, device) for v in variants}
    for alg in students.values():  # a first update: Adam's state exists, as in training
        torch.manual_seed(0)
        fill(alg, args.worlds, steps, args.obs, 0, device)
        alg.update()
    seconds = {v: [] for v in variants}
    weights = {}
    for r in range(args.rounds):
        for v, alg in students.items():
            before = copy.deepcopy((alg.save(), alg.learning_rate))
            torch.manual_seed(r + 1)
            fill(alg, args.worlds, steps, args.obs, r + 1, device)
            if cuda:
                torch.cuda.synchronize()
            start = time.perf_counter()
            alg.update()
            if cuda:
                torch.cuda.synchronize()
            seconds[v].append(time.perf_counter() - start)
            weights[v] = [t.clone() for t in alg.save()["actor_state_dict"].values()]
            alg.load(before[0], None, strict=True)  # every round starts from the same student
            alg.learning_rate = before[1]
    same = all(
        all(torch.equal(a, b) for a, b in zip(weights["rsl_rl"], weights[v])) for v in variants
    )
    samples = steps * args.worlds
    print(f"PPO update on {device} of {samples} samples ({args.worlds} worlds x {steps} steps, "
          f"{params['num_learning_epochs']} x {params['num_mini_batches']}, "
          f"{params['hidden_dims']}), median of {args.rounds} interleaved rounds")  # fmt: skip
    reference = statistics.median(seconds["rsl_rl"])
    for v in variants:
        median = statistics.median(seconds[v])
        print(f"| {v} | {1e3 * median:.0f} ms | {reference / median:.2f}x |")
    print(f"same weights after the update: {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()
