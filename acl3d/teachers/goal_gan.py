"""GoalGAN (Florensa et al. 2018): a GAN that generates Goals Of Intermediate Difficulty.

Each generated goal is played `n_rollouts` times in a row; a goal whose mean success lies in
[goid_lb, goid_ub] is a positive example, any other a negative one. Every `update_size` labelled
goals the least-squares GAN is trained for `gan_train_iters` iterations so that the generator
proposes goals the discriminator believes are of intermediate difficulty. With probability
`p_old` an earlier mastered goal is replayed (with noise) to fight forgetting.

Where it starts: the GAN is pretrained on goals around the environment's easiest task
(`pretrain_around="easy"`, a Gaussian of std 10% of the range at the easy bounds its
`CurriculumProfile` declares), or on `initial_dist` when given: the paper pretrains on the goals
the initial policy reaches, i.e. easy ones. `pretrain_around="random"` is TeachMyAgent's start
under expert knowledge "low" (a Gaussian at a uniform random task); it is why stump-v1's GoalGAN
runs succeeded only where that random centre had low stumps.

The generator's tanh output spans twice the task space and is clipped (the paper's and
TeachMyAgent's map), so the bounds sit at tanh = +-0.5. An earlier acl3d version mapped it onto
exactly the space: goals on a bound (the easy corner of Stump Tracks) then needed a saturated
tanh, the pretrained generator collapsed onto the corner, every goal it proposed was mastered,
no goal was of intermediate difficulty and the GAN never trained again.

What stays inherent: the GAN is trained only when some goal of the last `update_size` got a
GOID label (with 2 rollouts: exactly one success), so it does not move while every generated
goal fails (or every one succeeds); exploration around it is the `state_noise_level` noise.

Differences from TeachMyAgent's version (why):
* All randomness comes from the teacher's seeded numpy and torch generators; the original
  reseeds the global numpy RNG and torch.
* Outcomes are matched to pending goals by value (within 1e-4 of the range), not by call order,
  so several environments can play goals concurrently and shuffled tasks may round-trip through
  float32.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from acl3d import validation
from acl3d.curriculum_profile import CurriculumProfile, easy_task
from acl3d.teachers.base import RunFacts
from acl3d.teachers.pending import PendingTasks
from acl3d.teachers.torch_utils import (
    TorchDrawsTeacher,
    check_positive,
    generator_state,
    load_generator_state,
    load_module_state,
    load_optimizer_state,
    mlp,
    module_state,
    optimizer_state,
    seeded_generator,
    trains,
)

PRETRAIN_CENTRES = ("easy", "random")


class _LeakyReLU(nn.LeakyReLU):
    def __init__(self):
        super().__init__(0.1)


class GoalGAN(TorchDrawsTeacher):
    """GoalGAN with TeachMyAgent's benchmark settings (see the module docstring)."""

    name = "goal-gan"
    needs = frozenset({"success"})
    uses_initial_dist = True

    @classmethod
    def run_params(cls, facts: RunFacts) -> dict[str, Any]:
        """Pretrained on the easy-task prior when known, else around the environment's easy
        side."""
        return {
            "use_pretrained_samples": True,
            "easy_at_high": sorted(facts.profile.easy_at_high),
            **super().run_params(facts),
        }

    def __init__(
        self,
        task_space,
        seed: int | None = None,
        state_noise_level: float = 0.1,
        success_distance_threshold: float = 0.01,
        update_size: int = 100,
        n_rollouts: int = 2,
        goid_lb: float = 0.25,
        goid_ub: float = 0.75,
        p_old: float = 0.1,
        use_pretrained_samples: bool = True,
        initial_dist: dict | None = None,
        nb_pretrain_samples: int = 1000,
        pretrain_iters: int = 500,
        gan_train_iters: int = 250,
        batch_size: int = 64,
        generator_hidden: tuple[int, ...] = (256, 256),
        discriminator_hidden: tuple[int, ...] = (128, 128),
        lr: float = 1e-3,
        pretrain_around: str = "easy",
        easy_at_high=CurriculumProfile.easy_at_high,
    ):
        super().__init__(task_space, seed)
        validation.choice("pretrain_around", pretrain_around, PRETRAIN_CENTRES)
        self.state_noise_level = check_positive(
            "state_noise_level", state_noise_level, allow_zero=True
        )
        self.success_distance_threshold = check_positive(
            "success_distance_threshold", success_distance_threshold, allow_zero=True
        )
        self.update_size = check_positive("update_size", update_size, integer=True)
        self.n_rollouts = check_positive("n_rollouts", n_rollouts, integer=True)
        validation.real("goid_lb", goid_lb, 0.0, 1.0)
        validation.real("goid_ub", goid_ub, 0.0, 1.0)
        validation.real("p_old", p_old, 0.0, 1.0)
        if not goid_lb <= goid_ub:
            raise ValueError(
                f"goid_lb and goid_ub must satisfy 0 <= goid_lb <= goid_ub <= 1, got {goid_lb!r}, {goid_ub!r}"
            )
        self.goid_lb, self.goid_ub = float(goid_lb), float(goid_ub)
        if not 0.0 <= float(p_old) <= 1.0:
            raise ValueError(f"p_old must be in [0, 1], got {p_old!r}")
        self.p_old = float(p_old)
        self.gan_train_iters = check_positive("gan_train_iters", gan_train_iters, integer=True)
        self.batch_size = check_positive("batch_size", batch_size, integer=True)
        lr = check_positive("lr", lr)
        for what, hidden in (
            ("generator_hidden", generator_hidden),
            ("discriminator_hidden", discriminator_hidden),
        ):
            if not hidden or any(not isinstance(h, (int, np.integer)) or h < 1 for h in hidden):
                raise ValueError(
                    f"{what} must be a non-empty list of positive layer sizes, got {hidden!r}"
                )

        self.centre = (self.mins + self.maxs) / 2
        self.half_range = (self.maxs - self.mins) / 2
        self.span = self.maxs - self.mins
        self._match_tol = 1e-4 * self.span + 1e-6
        self.gen = seeded_generator(self.seed)
        self.generator = nn.Sequential(
            mlp([self.dim, *generator_hidden, self.dim], self.gen, nn.ReLU), nn.Tanh()
        )
        self.discriminator = mlp([self.dim, *discriminator_hidden, 1], self.gen, _LeakyReLU)
        self.gen_opt = torch.optim.RMSprop(self.generator.parameters(), lr=lr)
        self.dis_opt = torch.optim.RMSprop(self.discriminator.parameters(), lr=lr)

        self._queue: list[np.ndarray] = []  # repeats of the current goal still to hand out
        self._pending = PendingTasks(self.dim, 1.0, self._match_tol)  # goal -> its successes so far
        self._labelled_goals: list[np.ndarray] = []
        self._labels: list[float] = []
        self.success_buffer: list[np.ndarray] = []

        if use_pretrained_samples:
            nb = check_positive("nb_pretrain_samples", nb_pretrain_samples, integer=True)
            iters = check_positive("pretrain_iters", pretrain_iters, integer=True)
            if initial_dist is None:
                centre = (
                    easy_task(self.task_space, easy_at_high)
                    if pretrain_around == "easy"
                    else self.rng.uniform(self.mins, self.maxs)
                )
                initial_dist = {"mean": centre, "variance": np.diag((0.1 * self.span) ** 2)}
            self._pretrain(initial_dist, nb, iters)

    # ------------------------------------------------------------------ coordinates
    def _to_unit(self, goals: np.ndarray) -> np.ndarray:
        """Task space -> [-0.5, 0.5]^d (constant dimensions -> 0)."""
        return np.divide(
            goals - self.centre,
            2 * self.half_range,
            out=np.zeros_like(goals),
            where=self.half_range > 0,
        )

    def _from_unit(self, out: np.ndarray) -> np.ndarray:
        return self.clip(self.centre + out * 2 * self.half_range)

    # ------------------------------------------------------------------ GAN
    def _generate(self, n: int, gen: torch.Generator | None = None) -> np.ndarray:
        with torch.no_grad():
            z = torch.randn(n, self.dim, generator=self.gen if gen is None else gen)
            return self._from_unit(self.generator(z).double().numpy())

    @trains
    def _train(self, goals: np.ndarray, labels: np.ndarray, iters: int) -> None:
        """LSGAN: D pushes real positives to +1, real negatives and fakes to -1; G pushes fakes to +1."""
        x_all = torch.as_tensor(self._to_unit(goals), dtype=torch.float32)
        y_all = torch.as_tensor(labels, dtype=torch.float32).reshape(-1, 1)
        n, b = len(goals), self.batch_size
        for _ in range(iters):
            idx = torch.randint(n, (b,), generator=self.gen)
            z = torch.randn(b, self.dim, generator=self.gen)
            fake = self.generator(z).detach()
            d_loss = ((2 * y_all[idx] - 1 - self.discriminator(x_all[idx])) ** 2).mean()
            d_loss = d_loss + ((-1 - self.discriminator(fake)) ** 2).mean()
            self.dis_opt.zero_grad()
            d_loss.backward()
            self.dis_opt.step()
            z = torch.randn(b, self.dim, generator=self.gen)
            g_loss = ((self.discriminator(self.generator(z)) - 1) ** 2).mean()
            self.gen_opt.zero_grad()
            g_loss.backward()
            self.gen_opt.step()
        self.bk["dis_log_loss"].append(float(d_loss.detach()))
        self.bk["gen_log_loss"].append(float(g_loss.detach()))

    def _pretrain(self, initial_dist, nb: int, iters: int) -> None:
        """Train on `nb` positives drawn from the Gaussian `initial_dist`."""
        try:
            mean = np.asarray(initial_dist["mean"], dtype=np.float64).reshape(self.dim)
            cov = np.asarray(initial_dist["variance"], dtype=np.float64)
            cov = np.diag(cov) if cov.shape == (self.dim,) else cov.reshape(self.dim, self.dim)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(
                f"initial_dist must be {{'mean': ({self.dim},), 'variance': ({self.dim}, {self.dim})}}, got {initial_dist!r} ({exc})"
            ) from None
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            raise ValueError("initial_dist: mean and variance must be finite")
        samples = self.clip(self.rng.multivariate_normal(mean, cov, size=nb, method="eigh"))
        self._train(samples, np.ones(nb), iters)

    # ------------------------------------------------------------------ sampling
    def _noisy(self, goal: np.ndarray) -> np.ndarray:
        return self.clip(
            goal + self.rng.normal(0.0, 1.0, self.dim) * self.state_noise_level * self.span
        )

    def _sample(self) -> np.ndarray:
        if self._queue:
            return self._queue.pop(0)
        if not self.success_buffer or self.rng.random() >= self.p_old:
            goal = self._noisy(self._generate(1)[0]).astype(np.float32)
            self._pending.add(goal, [])
            self._queue = [goal] * (self.n_rollouts - 1)
            return goal
        old = self.success_buffer[self.rng.integers(len(self.success_buffer))]
        return self._noisy(old)

    def _non_exploratory_sample(self) -> np.ndarray:
        return self._generate(1)[0]

    # ------------------------------------------------------------------ feedback
    def _episodic_update(self, task: np.ndarray, reward: float, is_success: bool) -> None:
        proposal = self._pending.oldest(task)
        if proposal is not None:
            outcomes = self._pending.payload(proposal)
            outcomes.append(float(is_success))
            if len(outcomes) >= self.n_rollouts:
                goal, _ = self._pending.pop(proposal)
                self._label(goal, float(np.mean(outcomes)))
        self.bk["episodes"].append(self.nb_episodes)
        if len(self._labels) >= self.update_size:
            if any(self._labels):
                self._train(
                    np.stack(self._labelled_goals), np.array(self._labels), self.gan_train_iters
                )
            self._labelled_goals, self._labels = [], []

    def _label(self, goal: np.ndarray, success_rate: float) -> None:
        self._labelled_goals.append(goal)
        self._labels.append(float(self.goid_lb <= success_rate <= self.goid_ub))
        if success_rate > self.goid_ub:
            threshold = self.success_distance_threshold * float(np.linalg.norm(self.span))
            if all(np.linalg.norm(goal - g) > threshold for g in self.success_buffer):
                self.success_buffer.append(goal)

    def plot_state(self) -> dict[str, Any]:
        """200 generator samples (no exploration noise; fixed latents, so plotting leaves the
        teacher's random stream alone) and the replay buffer."""
        return {
            "kind": "samples",
            "tasks": self._generate(200, seeded_generator(self.seed)),
            "success_buffer": np.array(self.success_buffer).reshape(-1, self.dim),
        }

    # ------------------------------------------------------------------ checkpointing
    def _extra_state(self) -> dict[str, Any]:
        return {
            "generator": module_state(self.generator),
            "discriminator": module_state(self.discriminator),
            "gen_opt": optimizer_state(self.gen_opt),
            "dis_opt": optimizer_state(self.dis_opt),
            "torch_rng": generator_state(self.gen),
            "queue": [g.copy() for g in self._queue],
            "pending": [
                {"goal": g.astype(np.float32), "outcomes": list(o)}
                for g, o in self._pending.items()
            ],
            "labelled_goals": [g.copy() for g in self._labelled_goals],
            "labels": list(self._labels),
            "success_buffer": [g.copy() for g in self.success_buffer],
        }

    def _load_extra_state(self, extra: dict[str, Any]) -> None:
        load_module_state(self.generator, extra["generator"])
        load_module_state(self.discriminator, extra["discriminator"])
        load_optimizer_state(self.gen_opt, extra["gen_opt"])
        load_optimizer_state(self.dis_opt, extra["dis_opt"])
        load_generator_state(self.gen, extra["torch_rng"])
        self._queue = [np.asarray(g, dtype=np.float32) for g in extra["queue"]]
        self._pending.load(
            (np.asarray(p["goal"], dtype=np.float32), [float(o) for o in p["outcomes"]])
            for p in extra["pending"]
        )
        self._labelled_goals = [np.asarray(g, dtype=np.float64) for g in extra["labelled_goals"]]
        self._labels = [float(v) for v in extra["labels"]]
        self.success_buffer = [np.asarray(g, dtype=np.float64) for g in extra["success_buffer"]]
