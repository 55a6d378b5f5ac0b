"""Helpers shared by the torch-based teachers (SPDL, GoalGAN, Setter-Solver).

Networks are built without touching torch's global RNG and initialised from the teacher's own
`torch.Generator`, and their weights, optimiser moments and generator state round-trip through
plain numpy arrays, so a saved teacher resumes bit-for-bit.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import torch
from torch import nn

from acl3d import validation
from acl3d.teachers.base import Teacher


def trains(method):
    """Runs a teacher's training step with autograd on, whatever the caller's mode: teachers learn
    inside a student's rollout (in the middle of an env step), which runs under
    `torch.inference_mode`."""

    @functools.wraps(method)
    def with_autograd(*args, **kwargs):
        with torch.inference_mode(False), torch.enable_grad():
            return method(*args, **kwargs)

    return with_autograd


def check_positive(name: str, value, integer: bool = False, allow_zero: bool = False):
    """Validate a hyperparameter: finite, > 0 (or >= 0), integer if asked; raise naming it."""
    if integer:
        return validation.count(name, value, minimum=0 if allow_zero else 1)
    return validation.positive(name, value, allow_zero=allow_zero)


def seeded_generator(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(int(seed))


class TorchDrawsTeacher(Teacher):
    """A teacher that draws from a `torch.Generator`, `self.gen`, besides `self.rng`."""

    gen: torch.Generator

    @contextmanager
    def _own_streams(self, seed: int) -> Iterator[None]:
        saved, self.gen = self.gen, seeded_generator(seed)
        try:
            with super()._own_streams(seed):
                yield
        finally:
            self.gen = saved


def linear(n_in: int, n_out: int, gen: torch.Generator, gain: float = 1.0) -> nn.Linear:
    """A Linear layer with Xavier-uniform weights and zero biases, drawn from `gen` only."""
    layer = nn.utils.skip_init(nn.Linear, n_in, n_out)
    with torch.no_grad():
        nn.init.xavier_uniform_(layer.weight, gain=gain, generator=gen)
        layer.bias.zero_()
    return layer


def mlp(sizes: list[int], gen: torch.Generator, activation: type[nn.Module]) -> nn.Sequential:
    """Linear layers of `sizes` with `activation` between them (none after the last)."""
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(linear(a, b, gen))
        if i < len(sizes) - 2:
            layers.append(activation())
    return nn.Sequential(*layers)


def module_state(module: nn.Module) -> dict[str, np.ndarray]:
    return {k: v.detach().cpu().numpy().copy() for k, v in module.state_dict().items()}


def load_module_state(module: nn.Module, state: dict[str, Any]) -> None:
    module.load_state_dict({k: torch.as_tensor(np.asarray(v)) for k, v in state.items()})


def optimizer_state(opt: torch.optim.Optimizer) -> dict[str, dict[str, np.ndarray]]:
    """Per-parameter moments only; hyperparameters come from the constructor on load."""
    return {
        str(k): {name: torch.as_tensor(v).detach().cpu().numpy().copy() for name, v in s.items()}
        for k, s in opt.state_dict()["state"].items()
    }


def load_optimizer_state(opt: torch.optim.Optimizer, state: dict[str, Any]) -> None:
    moments = {
        int(k): {n: torch.as_tensor(np.asarray(v)) for n, v in s.items()} for k, s in state.items()
    }
    opt.load_state_dict({"state": moments, "param_groups": opt.state_dict()["param_groups"]})


def generator_state(gen: torch.Generator) -> np.ndarray:
    return gen.get_state().numpy().copy()


def load_generator_state(gen: torch.Generator, state) -> None:
    gen.set_state(torch.as_tensor(np.asarray(state, dtype=np.uint8)))


def conjugate_gradient(fvp, b: torch.Tensor, iters: int, residual_tol: float) -> torch.Tensor:
    """Solve F x = b for a symmetric positive-definite F given only x -> F x."""
    x = torch.zeros_like(b)
    r, p = b.clone(), b.clone()
    rr = r @ r
    for _ in range(iters):
        if rr < residual_tol:
            break
        fp = fvp(p)
        step = rr / (p @ fp)
        x = x + step * p
        r = r - step * fp
        rr_new = r @ r
        p = r + (rr_new / rr) * p
        rr = rr_new
    return x
