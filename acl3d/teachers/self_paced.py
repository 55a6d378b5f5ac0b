"""Self-Paced Deep RL (SPDL, Klink et al. 2020): a Gaussian context distribution that climbs
the student's value landscape while being pulled towards a target distribution.

Every `update_frequency` environment steps (after `update_offset` steps), the buffered contexts c_i
of finished episodes are scored by the student's value of their initial state V_i, and the context
distribution p_theta takes one KL-constrained natural-gradient step on

    L(theta) = mean_i[p_theta(c_i) / p_old(c_i) * V_i] - alpha * KL(p_theta || target),
    subject to KL(p_old || p_theta) <= max_kl,

with alpha = zeta * max(0, performance) / KL(p || target) once `alpha_offset` updates have passed
(TeachMyAgent's PercentageAlphaFunction). The step is TRPO's: conjugate gradient on the Fisher
matrix, scaled to the KL bound, then a halving line search.

Differences from the original (why):
* Without a value estimator (or when it returns None, or when an episode's initial state was not
  recorded) V_i is the discounted return measured from that episode's step rewards: an unbiased
  Monte-Carlo estimate of the same value, so the teacher also works with students that expose no
  V network. An episode for which no step reward was received uses its episodic return.
* Steps may come from several environments interleaved: `step_update(..., stream=k)` keeps one
  discounted sum per stream, and finished episodes are matched to `episodic_update` calls in the
  order they finish (the order the training loop reports them).
* The line search accepts a step only if it satisfies the KL bound (with TRPO's 1.5 slack) AND
  improves L; the original accepts either, which can leave the trust region.
* Constant dimensions (min == max) are kept out of the Gaussian instead of getting variance 1e-6,
  which keeps the Fisher matrix well conditioned; they always sample their single value.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np
import torch
from torch.distributions import MultivariateNormal, kl_divergence

from acl3d import validation
from acl3d.teachers import histories
from acl3d.teachers.base import RunFacts, Teacher
from acl3d.teachers.step_streams import DiscountedReturns
from acl3d.teachers.torch_utils import check_positive, conjugate_gradient, trains

_CG_DEFAULTS = {
    "n_epochs_line_search": 10,
    "n_epochs_cg": 10,
    "cg_damping": 1e-2,
    "cg_residual_tol": 1e-10,
}


class SelfPaced(Teacher):
    """SPDL with TeachMyAgent's benchmark settings (see the module docstring)."""

    name = "self-paced"
    needs = frozenset({"step_rewards", "initial_states", "value_estimator"})
    uses_initial_dist = True

    @classmethod
    def plot_history(cls, bk, low, high, steps):
        """The Gaussian after each update (updates count environment steps)."""
        return histories.gaussians(bk, steps)

    @classmethod
    def toy_params(cls, facts: RunFacts) -> dict[str, Any]:
        """A toy episode is one step: update every 250 episodes after the first 1000."""
        return {"update_frequency": 250, "update_offset": 1000}

    def __init__(
        self,
        task_space,
        seed: int | None = None,
        update_frequency: int = 50000,
        update_offset: int = 200000,
        alpha_offset: int = 10,
        zeta: float = 0.25,
        max_kl: float = 0.1,
        std_lower_bound=None,
        kl_threshold: float | None = None,
        use_avg_performance: bool = True,
        max_context_buffer_size: int = 1000,
        reset_contexts: bool = True,
        discount_factor: float = 0.99,
        initial_dist: dict | None = None,
        target_dist: dict | None = None,
        cg_parameters: dict | None = None,
    ):
        super().__init__(task_space, seed)
        self.update_frequency = check_positive("update_frequency", update_frequency, integer=True)
        self.update_offset = check_positive(
            "update_offset", update_offset, integer=True, allow_zero=True
        )
        self.alpha_offset = check_positive(
            "alpha_offset", alpha_offset, integer=True, allow_zero=True
        )
        self.zeta = check_positive("zeta", zeta, allow_zero=True)
        self.max_kl = check_positive("max_kl", max_kl)
        self.max_context_buffer_size = check_positive(
            "max_context_buffer_size", max_context_buffer_size, integer=True
        )
        validation.real("discount_factor", discount_factor, 0.0, 1.0, exclusive_low=True)
        self.discount_factor = float(discount_factor)
        self.use_avg_performance = bool(use_avg_performance)
        self.reset_contexts = bool(reset_contexts)
        cg = dict(_CG_DEFAULTS)
        unknown = set(cg_parameters or {}) - set(cg)
        if unknown:
            raise ValueError(
                f"cg_parameters: unknown key(s) {sorted(unknown)}; valid: {sorted(cg)}"
            )
        cg.update(cg_parameters or {})
        self.n_epochs_line_search = check_positive(
            "cg_parameters['n_epochs_line_search']", cg["n_epochs_line_search"], integer=True
        )
        self.n_epochs_cg = check_positive(
            "cg_parameters['n_epochs_cg']", cg["n_epochs_cg"], integer=True
        )
        self.cg_damping = check_positive(
            "cg_parameters['cg_damping']", cg["cg_damping"], allow_zero=True
        )
        self.cg_residual_tol = check_positive(
            "cg_parameters['cg_residual_tol']", cg["cg_residual_tol"]
        )

        self.free = self.maxs > self.mins
        self.k = int(self.free.sum())
        span = (self.maxs - self.mins)[self.free]
        if (std_lower_bound is None) != (kl_threshold is None):
            raise ValueError("std_lower_bound and kl_threshold go together: give both or neither")
        self.kl_threshold = (
            None
            if kl_threshold is None
            else check_positive("kl_threshold", kl_threshold, allow_zero=True)
        )
        self.std_lower_bound = None
        if std_lower_bound is not None:
            lb = np.broadcast_to(np.asarray(std_lower_bound, dtype=np.float64), (self.dim,))[
                self.free
            ]
            if not np.all(np.isfinite(lb)) or np.any(lb <= 0):
                raise ValueError(
                    f"std_lower_bound must be > 0 (scalar or one per dimension), got {std_lower_bound!r}"
                )
            self.std_lower_bound = lb.copy()

        centre = (self.mins + self.maxs)[self.free] / 2
        if initial_dist is None:  # TeachMyAgent's "subspace" helper: random mean, std 10% of range
            init = (self.rng.uniform(self.mins, self.maxs)[self.free], np.diag((0.1 * span) ** 2))
        else:
            init = self._check_dist("initial_dist", initial_dist)
        target = (
            (centre, np.diag((span / 4) ** 2))
            if target_dist is None
            else self._check_dist("target_dist", target_dist)
        )
        self.theta = self._pack(*init)
        self.target_mean, self.target_cov = target

        self.steps = 0
        self.algo_iterations = 0
        self._streams = DiscountedReturns(self.discount_factor)  # each stream's running episode
        self._finished_returns: deque[float] = deque()
        self._perf_returns: list[float] = []
        self._pending_state: np.ndarray | None = None
        self._buffer: deque[tuple[np.ndarray | None, np.ndarray, float]] = deque(
            maxlen=self.max_context_buffer_size
        )

    # ------------------------------------------------------------------ distributions
    def _check_dist(self, what: str, dist) -> tuple[np.ndarray, np.ndarray]:
        try:
            mean = np.asarray(dist["mean"], dtype=np.float64).reshape(self.dim)
            cov = np.asarray(dist["variance"], dtype=np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(
                f"{what} must be {{'mean': ({self.dim},), 'variance': ({self.dim}, {self.dim})}}, got {dist!r} ({exc})"
            ) from None
        if cov.shape == (self.dim,):
            cov = np.diag(cov)
        if cov.shape != (self.dim, self.dim) or not (
            np.all(np.isfinite(cov)) and np.all(np.isfinite(mean))
        ):
            raise ValueError(
                f"{what}: variance must be a finite ({self.dim}, {self.dim}) covariance and mean finite, got shapes {mean.shape}, {cov.shape}"
            )
        cov = (cov + cov.T)[np.ix_(self.free, self.free)] / 2
        if self.k and np.linalg.eigvalsh(cov).min() <= 0:
            raise ValueError(
                f"{what}: variance must be positive definite on the non-constant dimensions"
            )
        return mean[self.free], cov

    def _pack(self, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """(mean, covariance) -> [mean, log diag(L), strict lower triangle of L]."""
        if self.k == 0:
            return np.zeros(0)
        chol = np.linalg.cholesky(cov)
        rows, cols = np.tril_indices(self.k, -1)
        return np.concatenate([mean, np.log(np.diag(chol)), chol[rows, cols]])

    def _unpack(self, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        k = self.k
        mean = theta[:k]
        rows, cols = np.tril_indices(k, -1)
        chol = torch.diag(torch.exp(theta[k : 2 * k]))
        chol = chol.index_put((torch.as_tensor(rows), torch.as_tensor(cols)), theta[2 * k :])
        return mean, chol

    def _dist(self, theta: torch.Tensor) -> MultivariateNormal:
        mean, chol = self._unpack(theta)
        return MultivariateNormal(mean, scale_tril=chol)

    def _target(self) -> MultivariateNormal:
        return MultivariateNormal(
            torch.as_tensor(self.target_mean), covariance_matrix=torch.as_tensor(self.target_cov)
        )

    def mean_covariance(self) -> tuple[np.ndarray, np.ndarray]:
        """The context distribution over all dimensions (constant ones: their value, variance 0)."""
        mean, cov = self.mins.copy(), np.zeros((self.dim, self.dim))
        if self.k:
            m, chol = self._unpack(torch.as_tensor(self.theta))
            mean[self.free] = m.numpy()
            cov[np.ix_(self.free, self.free)] = (chol @ chol.T).numpy()
        return mean, cov

    def target_kl(self) -> float:
        if self.k == 0:
            return 0.0
        with torch.no_grad():
            return float(kl_divergence(self._dist(torch.as_tensor(self.theta)), self._target()))

    def plot_state(self) -> dict[str, Any]:
        mean, cov = self.mean_covariance()
        return {"kind": "gaussian", "mean": mean, "covariance": cov}

    # ------------------------------------------------------------------ sampling
    def _sample(self) -> np.ndarray:
        return self._sample_batch(1)[0]

    def _sample_batch(self, n: int) -> np.ndarray:
        """n draws, the distribution unpacked once (it changes only at updates)."""
        tasks = np.tile(self.mins, (n, 1))
        if self.k:
            mean, chol = (t.numpy() for t in self._unpack(torch.as_tensor(self.theta)))
            for task in tasks:
                task[self.free] = mean + chol @ self.rng.standard_normal(self.k)
        return self.clip(tasks)

    # ------------------------------------------------------------------ feedback
    def _step_update(self, state, action, reward, next_state, done, stream: int) -> None:
        self._step_updates(
            None, None, np.array([reward]), None, np.array([done]), np.array([stream])
        )

    def _step_updates(self, states, actions, rewards, next_states, dones, streams) -> None:
        """Accumulate each stream's discounted return; update every `update_frequency` steps
        (a step's place in the batch does not matter: an update reads finished episodes only)."""
        self._finished_returns.extend(self._streams.add(streams, rewards, dones).tolist())
        end, every = self.steps + len(streams), self.update_frequency
        first = max(self.steps + 1, self.update_offset)
        for step in range(-(-first // every) * every, end + 1, every):
            self.steps = step  # the update records the step it happened at
            self._update_distribution()
        self.steps = end

    def _record_initial_state(self, task: np.ndarray, state: np.ndarray) -> None:
        self._pending_state = np.array(state, dtype=np.float32).reshape(-1)

    def _episodic_update(self, task: np.ndarray, reward: float, is_success: bool) -> None:
        ret = self._finished_returns.popleft() if self._finished_returns else reward
        self._buffer.append((self._pending_state, task[self.free].copy(), float(ret)))
        self._perf_returns.append(float(ret))
        self._pending_state = None

    def _values(self, states: list, returns: np.ndarray) -> np.ndarray:
        if any(s is None for s in states):
            return returns
        values = self.value_estimator(np.stack(states))
        if values is None:
            return returns
        values = np.asarray(values, dtype=np.float64).reshape(-1)
        if values.shape != returns.shape or not np.all(np.isfinite(values)):
            raise ValueError(
                f"value_estimator must return {returns.shape[0]} finite values, got shape {values.shape}"
            )
        return values

    # ------------------------------------------------------------------ the SPDL step
    @trains
    def _update_distribution(self) -> None:
        if not self._buffer:
            return
        states = [b[0] for b in self._buffer]
        contexts = torch.as_tensor(np.stack([b[1] for b in self._buffer]))
        values = torch.as_tensor(self._values(states, np.array([b[2] for b in self._buffer])))
        perf = (
            float(np.mean(self._perf_returns)) if self.use_avg_performance else float(values.mean())
        )
        if self.reset_contexts:
            self._buffer.clear()
        self._perf_returns = []
        if self.k:
            alpha = 0.0
            if self.algo_iterations >= self.alpha_offset:
                alpha = min(1e5, self.zeta * max(0.0, perf) / max(self.target_kl(), 1e-10))
            self._natural_gradient_step(contexts, values, alpha)
            self._apply_std_lower_bound()
        self.algo_iterations += 1
        mean, cov = self.mean_covariance()
        self.bk["mean"].append(mean)
        self.bk["covariance"].append(cov)
        self.bk["steps"].append(self.steps)
        self.bk["algo_iterations"].append(self.algo_iterations)
        self.bk["kl"].append(self.target_kl())

    def _natural_gradient_step(
        self, contexts: torch.Tensor, values: torch.Tensor, alpha: float
    ) -> None:
        old_theta = torch.as_tensor(self.theta)
        old_dist = self._dist(old_theta)
        old_logp = old_dist.log_prob(contexts).detach()
        target = self._target()

        def objective(theta):
            dist = self._dist(theta)
            ratio = torch.exp(dist.log_prob(contexts) - old_logp)
            return (ratio * values).mean() - alpha * kl_divergence(dist, target)

        def trust_kl(theta):
            return kl_divergence(old_dist, self._dist(theta))

        theta = old_theta.clone().requires_grad_(True)
        f_old = objective(theta)
        (grad,) = torch.autograd.grad(f_old, theta)
        theta_kl = old_theta.clone().requires_grad_(True)
        (grad_kl,) = torch.autograd.grad(trust_kl(theta_kl), theta_kl, create_graph=True)

        def fvp(v):
            (hv,) = torch.autograd.grad(grad_kl @ v, theta_kl, retain_graph=True)
            return hv + self.cg_damping * v

        direction = conjugate_gradient(fvp, grad, self.n_epochs_cg, self.cg_residual_tol)
        shs = float(direction @ fvp(direction))
        if not math.isfinite(shs) or shs <= 0:
            return
        full_step = math.sqrt(2 * self.max_kl / shs) * direction
        f_old = float(f_old.detach())
        with torch.no_grad():
            for i in range(self.n_epochs_line_search):
                new = old_theta + full_step * 0.5**i
                kl, f_new = float(trust_kl(new)), float(objective(new))
                if math.isfinite(f_new) and kl <= 1.5 * self.max_kl and f_new > f_old:
                    self.theta = new.numpy().copy()
                    return

    def _apply_std_lower_bound(self) -> None:
        if self.std_lower_bound is None or self.target_kl() <= self.kl_threshold:
            return
        k = self.k
        self.theta[k : 2 * k] = np.maximum(self.theta[k : 2 * k], np.log(self.std_lower_bound))

    # ------------------------------------------------------------------ checkpointing
    def _extra_state(self) -> dict[str, Any]:
        return {
            "theta": self.theta.copy(),
            "target_mean": self.target_mean,
            "target_cov": self.target_cov,
            "steps": self.steps,
            "algo_iterations": self.algo_iterations,
            "streams": self._streams.state(),
            "finished_returns": list(self._finished_returns),
            "perf_returns": list(self._perf_returns),
            "pending_state": self._pending_state,
            "buffer": [{"state": s, "context": c, "return": r} for s, c, r in self._buffer],
        }

    def _load_extra_state(self, extra: dict[str, Any]) -> None:
        self.theta = np.asarray(extra["theta"], dtype=np.float64).copy()
        self.target_mean = np.asarray(extra["target_mean"], dtype=np.float64)
        self.target_cov = np.asarray(extra["target_cov"], dtype=np.float64)
        self.steps = int(extra["steps"])
        self.algo_iterations = int(extra["algo_iterations"])
        self._streams.load_state(extra["streams"])
        self._finished_returns = deque(float(r) for r in extra["finished_returns"])
        self._perf_returns = [float(r) for r in extra["perf_returns"]]
        ps = extra["pending_state"]
        self._pending_state = None if ps is None else np.asarray(ps, dtype=np.float32)
        buffer = [
            (
                None if b["state"] is None else np.asarray(b["state"], dtype=np.float32),
                np.asarray(b["context"], dtype=np.float64),
                float(b["return"]),
            )
            for b in extra["buffer"]
        ]
        self._buffer = deque(buffer, maxlen=self.max_context_buffer_size)
