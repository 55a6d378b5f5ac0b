"""Several policy snapshots acting at once: block b of the observations is acted on by
snapshot b, through one batched matrix product a layer instead of one forward a snapshot.

The many-world evaluator plays the policies of several evaluation steps side by side on a few
hundred worlds, where a GPU step is paced by the host's kernel launches rather than by the
arithmetic: a forward a snapshot costs about twenty launches and the Python of rsl_rl's modules,
a stack costs that once. Each block's actions depend only on its own snapshot's weights and
generator (a batched product computes each block alone), so a snapshot scores the same whatever
it is played beside; on the CPU bit for bit, and the same actions as the snapshot alone from 16
worlds a block (below that torch multiplies through other kernels, a few ulp apart).
"""

from __future__ import annotations

import torch
from rsl_rl.modules.normalization import EmpiricalNormalization
from torch import nn

from acl3d.training.torch_student.rsl_ppo import PolicySnapshot


class PolicyStack:
    """`snapshots` (of one spec, on one device) as one policy over `len(snapshots)` blocks of
    equally many worlds; generators as `PolicySnapshot`'s, one a block (None: its mean action)."""

    def __init__(self, snapshots: list[PolicySnapshot]):
        first = snapshots[0]
        if any(s.spec != first.spec for s in snapshots):
            raise ValueError("snapshots: a stack plays snapshots of one spec (sizes, layers)")
        self.blocks, self.device = len(snapshots), first.device
        self.observation_size, self.action_size = first.observation_size, first.action_size
        self.low, self.high = first.low, first.high
        actors = [s.actor for s in snapshots]
        with torch.inference_mode():
            self.shift, self.scale = _stacked_normalisers([a.obs_normalizer for a in actors])
            self.layers = [_stacked_layer(depth) for depth in zip(*(a.mlp for a in actors))]
            self.noise_std = torch.stack([_noise_std(s) for s in snapshots]).unsqueeze(1)

    def __call__(self, obs: torch.Tensor, generators: list) -> torch.Tensor:
        """Actions for (blocks * n, obs) observations, block b by snapshot b: its mean or,
        where `generators[b]` is a generator, sampled from it; clipped to the action bounds."""
        if len(generators) != self.blocks:
            raise ValueError(f"generators: one a block ({self.blocks}), got {len(generators)}")
        with torch.inference_mode():
            x = obs.to(self.device, torch.float32).reshape(self.blocks, -1, self.observation_size)
            x = (x - self.shift) / self.scale
            for layer in self.layers:
                x = layer(x)
            if any(g is not None for g in generators):
                noise = torch.stack([_standard_normal(x.shape[1:], g, x) for g in generators])
                x = x + noise * self.noise_std
            return x.clamp(self.low, self.high).reshape(-1, self.action_size)


class _StackedLinear:
    """The linear layers of one depth, one a block: a batched `x @ W.T + b`."""

    def __init__(self, linears: tuple[nn.Linear, ...]):
        self.weight = torch.stack([m.weight.T for m in linears])
        self.bias = torch.stack([m.bias for m in linears]).unsqueeze(1)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return torch.baddbmm(self.bias, x, self.weight)


def _stacked_layer(modules: tuple[nn.Module, ...]):
    """One depth of the snapshots' MLPs: their linear layers stacked, or their activation (an
    element-wise module without weights, the same in every snapshot)."""
    kind = type(modules[0])
    if any(type(m) is not kind for m in modules):
        raise ValueError("snapshots: a stack plays snapshots of one architecture")
    if kind is nn.Linear:
        return _StackedLinear(modules)
    if next(modules[0].parameters(), None) is not None or kind is nn.Unflatten:
        raise TypeError(f"snapshots: a stack cannot play an MLP layer of type {kind.__name__}")
    return modules[0]


def _stacked_normalisers(normalisers) -> tuple[torch.Tensor, torch.Tensor]:
    """The observation normalisers' `(x - mean) / (std + eps)` as stacked shifts and scales."""
    if any(not isinstance(n, EmpiricalNormalization) for n in normalisers):
        raise TypeError("snapshots: a stack plays actors with empirical observation normalisers")
    shift = torch.stack([n.mean for n in normalisers]).unsqueeze(1)
    scale = torch.stack([n.std + n.eps for n in normalisers]).unsqueeze(1)
    return shift, scale


def _noise_std(snapshot: PolicySnapshot) -> torch.Tensor:
    """The snapshot's action noise, by its distribution's own rules (floor, log or scalar)."""
    distribution = snapshot.actor.distribution
    distribution.update(torch.zeros(1, snapshot.action_size, device=snapshot.device))
    return distribution.std.reshape(snapshot.action_size)


def _standard_normal(shape, generator, like: torch.Tensor) -> torch.Tensor:
    """Standard normal draws from `generator`; zeros for a block acting on its mean."""
    if generator is None:
        return torch.zeros(shape, dtype=like.dtype, device=like.device)
    return torch.randn(shape, generator=generator, dtype=like.dtype, device=like.device)
