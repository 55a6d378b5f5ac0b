"""Setter-Solver (Racanière et al. 2020): a generative "setter" proposes goals of a requested
feasibility f, a "judge" predicts the feasibility of goals for the current student.

The setter is a conditional RealNVP flow from a standard-normal latent to (0, 1)^d (then rescaled
to the task space), conditioned on f ~ U(0, 1). Every `update_frequency` episodes the judge takes
one Adam step of sigmoid cross-entropy against the binary successes, and the setter one Adam step on

* feasibility: (judge_logit(G(z; f)) - logit(f))^2, so goals asked at feasibility f are judged so;
* validity: -log p(g + u | f) of the goals the student achieved (u ~ U(0, setter_loss_noise_ub));
* coverage: log p(G(z; f) | f) of its own samples, i.e. maximise the setter's entropy.

Differences from TeachMyAgent's version (why):
* The judge has the intended three hidden layers of 64 (the original passes one size too few
  and gets two).
* The feasibility and coverage terms are taken at fresh latents z ~ N(0, I) with the buffered
  feasibilities, the paper's expectation over z and f. TeachMyAgent takes them at the latents of
  the buffered goals, recovered by inverting the flow and fed back as constants: draws from
  N(0, I) too (the goals were proposed from them), so the gradient carries the same feasibility
  signal, at the goals the judge was just trained on. On the behavioural test's learner neither
  does better (docs/teachers.md).
* Every coupling starts as the identity (zero output weights, scale bias set so that the scale is
  1), so the untrained setter covers the space like sigmoid(N(0, 1)) instead of starting with the
  ~0.3^6 contraction that stacked scales of 1/pi + 0.01 give.
* Outcomes are matched to the goals the setter proposed by value (within 1e-4 of the range);
  episodes on tasks the setter did not propose are ignored (the flow needs the goal's f).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from acl3d.teachers.pending import PendingTasks
from acl3d.teachers.torch_utils import (
    TorchDrawsTeacher,
    check_positive,
    generator_state,
    linear,
    load_generator_state,
    load_module_state,
    load_optimizer_state,
    mlp,
    module_state,
    optimizer_state,
    seeded_generator,
    trains,
)

_F_MIN = 1e-8
_GOAL_CLIP = 1e-4
_IDENTITY_SCALE_LOGIT = 0.9103  # softplus_atan(0.9103) + 0.01 = 1.000


def softplus_atan(x: torch.Tensor) -> torch.Tensor:
    """A smooth positive function, linear for large x and ~1/(pi |x|) for very negative x."""
    x = 1e6 * torch.tanh(x / 1e6)
    return x * (torch.atan(x) / math.pi + 0.5) + 1.0 / math.pi


class _Highway(nn.Module):
    """Linear -> tanh -> 3 gated highway blocks -> Linear (the coupling's scale/shift network)."""

    def __init__(self, n_in: int, hidden: int, n_out: int, gen: torch.Generator, n_blocks: int = 3):
        super().__init__()
        self.inp = linear(n_in, hidden, gen)
        self.gates = nn.ModuleList(linear(hidden, hidden, gen) for _ in range(n_blocks))
        self.transforms = nn.ModuleList(linear(hidden, hidden, gen) for _ in range(n_blocks))
        self.out = linear(hidden, n_out, gen)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = torch.tanh(self.inp(x))
        for gate, transform in zip(self.gates, self.transforms):
            g = torch.sigmoid(gate(h))
            h = g * torch.tanh(transform(h)) + (1 - g) * h
        return self.out(h)


class _Coupling(nn.Module):
    """Affine coupling: the `trans` coordinates are scaled and shifted as a function of the `cond`
    coordinates and the feasibility."""

    def __init__(self, cond: list[int], trans: list[int], hidden: int, gen: torch.Generator):
        super().__init__()
        self.register_buffer("cond", torch.as_tensor(cond, dtype=torch.long))
        self.register_buffer("trans", torch.as_tensor(trans, dtype=torch.long))
        self.net = _Highway(len(cond) + 1, hidden, 2 * len(trans), gen)
        with torch.no_grad():
            self.net.out.weight.zero_()
            self.net.out.bias[: len(trans)] = _IDENTITY_SCALE_LOGIT

    def _scale_shift(self, x: torch.Tensor, f: torch.Tensor):
        s, t = self.net(torch.cat([x[:, self.cond], f], dim=1)).chunk(2, dim=1)
        return 0.01 + softplus_atan(s), t

    def forward(self, x, f):
        scale, shift = self._scale_shift(x, f)
        y = x.index_copy(1, self.trans, x[:, self.trans] * scale + shift)
        return y, torch.log(scale).sum(dim=1)

    def inverse(self, y, f):
        scale, shift = self._scale_shift(y, f)
        x = y.index_copy(1, self.trans, (y[:, self.trans] - shift) / scale)
        return x, -torch.log(scale).sum(dim=1)


class _Setter(nn.Module):
    """Conditional RealNVP: 3 blocks of (left->right, right->left, even->odd) couplings, sigmoid."""

    def __init__(self, dim: int, hidden: int, gen: torch.Generator, n_blocks: int = 3):
        super().__init__()
        half = dim // 2
        masks = [
            (list(range(half)), list(range(half, dim))),
            (list(range(half, dim)), list(range(half))),
            (list(range(0, dim, 2)), list(range(1, dim, 2))),
        ]
        # a coupling with nothing to transform (1-D goals) is the identity and is left out
        self.couplings = nn.ModuleList(
            _Coupling(cond, trans, hidden, gen)
            for _ in range(n_blocks)
            for cond, trans in masks
            if trans
        )
        self.dim = dim

    def _base_log_prob(self, z):
        return -0.5 * (z**2).sum(dim=1) - 0.5 * self.dim * math.log(2 * math.pi)

    def sample(self, z, f):
        """Goals in (0, 1)^d and their log-density."""
        x, log_det = z, torch.zeros(z.shape[0])
        for c in self.couplings:
            x, ld = c(x, f)
            log_det = log_det + ld
        log_det = log_det + (F.logsigmoid(x) + F.logsigmoid(-x)).sum(dim=1)
        return torch.sigmoid(x), self._base_log_prob(z) - log_det

    def log_prob(self, goals, f):
        x = torch.logit(goals)
        log_det = -(F.logsigmoid(x) + F.logsigmoid(-x)).sum(dim=1)
        for c in reversed(self.couplings):
            x, ld = c.inverse(x, f)
            log_det = log_det + ld
        return self._base_log_prob(x) + log_det


class SetterSolver(TorchDrawsTeacher):
    """Setter-Solver with TeachMyAgent's benchmark settings (see the module docstring)."""

    name = "setter-solver"
    needs = frozenset({"success"})

    def __init__(
        self,
        task_space,
        seed: int | None = None,
        update_frequency: int = 50,
        setter_loss_noise_ub: float = 0.1,
        setter_hidden_size: int = 64,
        judge_hidden: tuple[int, ...] = (64, 64, 64),
        setter_lr: float = 3e-4,
        judge_lr: float = 3e-4,
    ):
        super().__init__(task_space, seed)
        self.update_frequency = check_positive("update_frequency", update_frequency, integer=True)
        self.setter_loss_noise_ub = check_positive(
            "setter_loss_noise_ub", setter_loss_noise_ub, allow_zero=True
        )
        hidden = check_positive("setter_hidden_size", setter_hidden_size, integer=True)
        if not judge_hidden or any(
            not isinstance(h, (int, np.integer)) or h < 1 for h in judge_hidden
        ):
            raise ValueError(
                f"judge_hidden must be a non-empty list of positive layer sizes, got {judge_hidden!r}"
            )
        self.gen = seeded_generator(self.seed)
        self.setter = _Setter(self.dim, hidden, self.gen)
        self.judge = mlp([self.dim, *judge_hidden, 1], self.gen, nn.ReLU)
        self.setter_opt = torch.optim.Adam(
            self.setter.parameters(), lr=check_positive("setter_lr", setter_lr)
        )
        self.judge_opt = torch.optim.Adam(
            self.judge.parameters(), lr=check_positive("judge_lr", judge_lr)
        )
        self.span = self.maxs - self.mins
        self._match_tol = 1e-4 * self.span + 1e-6
        self._pending = PendingTasks(self.dim, 1.0, self._match_tol)  # task -> (unit goal, f)
        self._buffer: list[tuple[np.ndarray, float, float]] = []  # unit goal, f, success

    # ------------------------------------------------------------------ sampling
    def _propose(self, n: int, gen: torch.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        gen = self.gen if gen is None else gen
        with torch.no_grad():
            f = _F_MIN + (1 - _F_MIN) * torch.rand(n, 1, generator=gen)
            z = torch.randn(n, self.dim, generator=gen)
            goals, _ = self.setter.sample(z, f)
        return goals.double().numpy(), f.double().numpy()[:, 0]

    def _sample(self) -> np.ndarray:
        return self._sample_batch(1)[0]

    def _sample_batch(self, n: int) -> np.ndarray:
        """n goals from one pass of the flow (a pass per task cost ~2 ms)."""
        goals, f = self._propose(n)
        tasks = self.clip(self.rescale(goals)).astype(np.float32)
        for task, goal, feasibility in zip(tasks, goals, f.tolist()):
            self._pending.add(task, (goal, feasibility))
        return tasks

    def _non_exploratory_sample(self) -> np.ndarray:
        goals, _ = self._propose(1)
        return self.clip(self.rescale(goals[0]))

    def plot_state(self) -> dict[str, Any]:
        """200 setter samples from fixed draws, so plotting leaves the teacher's stream alone."""
        goals, f = self._propose(200, seeded_generator(self.seed))
        return {"kind": "samples", "tasks": self.clip(self.rescale(goals)), "feasibility": f}

    # ------------------------------------------------------------------ feedback
    def _episodic_update(self, task: np.ndarray, reward: float, is_success: bool) -> None:
        proposal = self._pending.oldest(task)
        if proposal is not None:
            _, (goal, f) = self._pending.pop(proposal)
            self._buffer.append((goal, f, float(is_success)))
        self.bk["episodes"].append(self.nb_episodes)
        if (self.nb_episodes + 1) % self.update_frequency == 0 and self._buffer:
            self._update()
            self._buffer = []

    @trains
    def _update(self) -> None:
        goals = torch.as_tensor(
            np.clip(np.stack([b[0] for b in self._buffer]), _GOAL_CLIP, 1 - _GOAL_CLIP),
            dtype=torch.float32,
        )
        f = torch.as_tensor([[b[1]] for b in self._buffer], dtype=torch.float32)
        success = torch.as_tensor([[b[2]] for b in self._buffer], dtype=torch.float32)

        judge_loss = F.binary_cross_entropy_with_logits(self.judge(goals), success)
        self.judge_opt.zero_grad()
        judge_loss.backward()
        self.judge_opt.step()

        setter_loss = sum(self.setter_losses(goals, f, success).values())
        self.setter_opt.zero_grad()
        setter_loss.backward()
        self.setter_opt.step()
        self.judge_opt.zero_grad()  # the setter loss also reached the judge; it must not leak

        self.bk["judge_loss"].append(float(judge_loss.detach()))
        self.bk["setter_loss"].append(float(setter_loss.detach()))

    def setter_losses(
        self, goals: torch.Tensor, f: torch.Tensor, success: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """The setter's three loss terms on a buffer of unit goals, their feasibilities (n, 1) and
        successes (n, 1). Their sum, unweighted as in TeachMyAgent, is what one setter step lowers."""
        z = torch.randn(len(goals), self.dim, generator=self.gen)
        generated, log_p = self.setter.sample(z, f)
        ok = success[:, 0] > 0
        validity = torch.zeros(())
        if ok.any():
            noise = self.setter_loss_noise_ub * torch.rand(
                int(ok.sum()), self.dim, generator=self.gen
            )
            noisy = torch.clamp(goals[ok] + noise, _GOAL_CLIP, 1 - _GOAL_CLIP)
            validity = -self.setter.log_prob(noisy, f[ok]).mean()
        return {
            "feasibility": ((self.judge(generated) - torch.logit(f)) ** 2).mean(),
            "validity": validity,
            "coverage": log_p.mean(),
        }

    # ------------------------------------------------------------------ checkpointing
    def _extra_state(self) -> dict[str, Any]:
        pending = self._pending.items()
        return {
            "setter": module_state(self.setter),
            "judge": module_state(self.judge),
            "setter_opt": optimizer_state(self.setter_opt),
            "judge_opt": optimizer_state(self.judge_opt),
            "torch_rng": generator_state(self.gen),
            # columns, not an entry a proposal: thousands wait at once on many worlds
            "proposals": {
                "tasks": np.array([t for t, _ in pending], np.float32).reshape(-1, self.dim),
                "goals": _rows([g for _, (g, _) in pending]),
                "f": np.array([f for _, (_, f) in pending], dtype=np.float64),
            },
            "outcomes": {
                "goals": _rows([g for g, _, _ in self._buffer]),
                "f": np.array([f for _, f, _ in self._buffer], dtype=np.float64),
                "success": np.array([s for _, _, s in self._buffer], dtype=np.float64),
            },
        }

    def _load_extra_state(self, extra: dict[str, Any]) -> None:
        load_module_state(self.setter, extra["setter"])
        load_module_state(self.judge, extra["judge"])
        load_optimizer_state(self.setter_opt, extra["setter_opt"])
        load_optimizer_state(self.judge_opt, extra["judge_opt"])
        load_generator_state(self.gen, extra["torch_rng"])
        proposals, outcomes = extra.get("proposals"), extra.get("outcomes")
        if proposals is None:  # a checkpoint written before: an entry a proposal and an outcome
            pending, buffer = extra["pending"], extra["buffer"]
            proposals = {
                "tasks": np.array([p["task"] for p in pending], np.float32),
                "goals": _rows([np.ravel(p["goal"]) for p in pending]),
                "f": np.array([float(p["f"]) for p in pending]),
            }
            outcomes = {
                "goals": _rows([np.ravel(b["goal"]) for b in buffer]),
                "f": np.array([float(b["f"]) for b in buffer]),
                "success": np.array([float(b["success"]) for b in buffer]),
            }
        tasks = np.asarray(proposals["tasks"], dtype=np.float32).reshape(-1, self.dim)
        self._pending.load(
            (task, (np.array(goal, dtype=np.float64), f))
            for task, goal, f in zip(tasks, proposals["goals"], proposals["f"].tolist())
        )
        self._buffer = [
            (np.array(goal, dtype=np.float64), f, success)
            for goal, f, success in zip(
                outcomes["goals"], outcomes["f"].tolist(), outcomes["success"].tolist()
            )
        ]


def _rows(vectors: list) -> np.ndarray:
    """Equal-length vectors as the rows of one float64 array ((0, 0) for none)."""
    return np.array(vectors, dtype=np.float64) if vectors else np.zeros((0, 0))
