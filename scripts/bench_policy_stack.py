"""The evaluator's actions a step: one forward a snapshot against the snapshots as one stack.

    python scripts/bench_policy_stack.py                      # CPU, 10 snapshots x 100 worlds
    python scripts/bench_policy_stack.py --device cuda        # a GPU, each call timed to its end

The many-world evaluator plays the ten policies of a run's evaluations side by side on 1,000
worlds; at that size a GPU step is paced by the host's kernel launches. This prints, for both
ways of acting (sampled actions, the benchmark preset's layers, Stump Tracks' sizes), the
operations torch dispatches a call (each one a kernel launch on a GPU, counted on any device)
and the median time a call over interleaved rounds, with the ratio to one forward a snapshot;
"same actions" says whether both give the same actions bit for bit.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from torch.utils._python_dispatch import TorchDispatchMode

from acl3d.training.torch_student import presets, rsl_ppo
from acl3d.training.torch_student.policy_stack import PolicyStack


class _CountOps(TorchDispatchMode):
    def __init__(self):
        super().__init__()
        self.count = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.count += 1
        return func(*args, **(kwargs or {}))


def snapshots(count: int, obs_size: int, act_size: int, preset: str, device: str) -> list:
    params = presets.hyperparameters(preset, 4096)
    spec = {"student": "rsl-ppo", "observation_size": obs_size, "action_size": act_size,
            **{k: params[k] for k in ("hidden_dims", "activation", "init_noise_std",
                                      "min_noise_std")}}  # fmt: skip
    out = []
    for k in range(count):
        torch.manual_seed(k)
        actor = rsl_ppo._models(spec, 1, device)[0]
        with torch.no_grad():
            actor.obs_normalizer._mean.normal_()
            actor.obs_normalizer._std.uniform_(0.5, 2.0)
        out.append(rsl_ppo.PolicySnapshot(spec, actor, -1.0, 1.0))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--snapshots", type=int, default=10)
    p.add_argument("--worlds", type=int, default=100, help="worlds a snapshot (the test set)")
    p.add_argument("--preset", default="benchmark", choices=presets.PRESETS)
    p.add_argument("--obs", type=int, default=24, help="observation size (Stump Tracks: 24)")
    p.add_argument("--actions", type=int, default=4, help="action size (classic biped: 4)")
    p.add_argument("--calls", type=int, default=200, help="calls a round")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    args = p.parse_args()
    device, n = torch.device(args.device), args.worlds
    torch.set_num_threads(1)
    policies = snapshots(args.snapshots, args.obs, args.actions, args.preset, args.device)
    stack = PolicyStack(policies)
    obs = 2.0 * torch.randn(args.snapshots * n, args.obs, device=device)

    def generators():
        return [torch.Generator(device).manual_seed(b) for b in range(args.snapshots)]

    def one_a_snapshot(gens):
        return torch.cat(
            [s(obs[b * n : (b + 1) * n], g) for b, (s, g) in enumerate(zip(policies, gens))]
        )

    def stacked(gens):
        return stack(obs, gens)

    ways = {"one forward a snapshot": one_a_snapshot, "one stack": stacked}
    same = torch.equal(one_a_snapshot(generators()), stacked(generators()))
    ops = {}
    for name, act in ways.items():
        with _CountOps() as counter:
            act(generators())
        ops[name] = counter.count
    seconds = {name: [] for name in ways}
    for _ in range(args.rounds):
        for name, act in ways.items():
            gens = generators()
            if device.type == "cuda":
                torch.cuda.synchronize()
            start = time.perf_counter()
            for _ in range(args.calls):
                act(gens)
            if device.type == "cuda":
                torch.cuda.synchronize()
            seconds[name].append((time.perf_counter() - start) / args.calls)
    hidden = presets.hyperparameters(args.preset, 4096)["hidden_dims"]
    print(f"actions of {args.snapshots} snapshots x {n} worlds on {device} (sampled, {hidden}), "
          f"median of {args.rounds} interleaved rounds of {args.calls} calls")  # fmt: skip
    medians = {name: statistics.median(times) for name, times in seconds.items()}
    for name, median in medians.items():
        ratio = medians["one forward a snapshot"] / median
        print(f"| {name} | {ops[name]} ops | {1e3 * median:.3f} ms | {ratio:.2f}x |")
    print(f"same actions: {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()
