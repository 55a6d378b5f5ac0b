"""Setter-Solver's losses term by term against the paper and TeachMyAgent: each term's sign (a
small step on it alone moves the setter the way the paper says; flipping a sign fails them), the feasibility drawn per goal,
and the judge trained on the raw success labels."""

from __future__ import annotations

import numpy as np
import torch
from torch.nn import functional as F

from acl3d.teachers.setter_solver import SetterSolver

SPACE = {"stump_height": [0.0, 3.0], "obstacle_spacing": [0.0, 6.0]}


def buffer(n: int = 32, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Unit goals, their feasibilities (n, 1) and successes (n, 1): the first third succeeded."""
    gen = torch.Generator().manual_seed(seed)
    goals = torch.rand(n, 2, generator=gen) * 0.98 + 0.01
    f = torch.rand(n, 1, generator=gen)
    success = (torch.arange(n) < n // 3).float().reshape(-1, 1)
    return goals, f, success


def step_on(teacher: SetterSolver, term: str, goals, f, success) -> None:
    """One small gradient step of the setter on one term alone; the teacher's draws are
    restored, so later calls see the same latents."""
    state = teacher.gen.get_state()
    sgd = torch.optim.SGD(teacher.setter.parameters(), lr=1e-3)
    sgd.zero_grad()
    teacher.setter_losses(goals, f, success)[term].backward()
    sgd.step()
    teacher.gen.set_state(state)


def test_feasibility_step_moves_goals_asked_feasible_toward_what_the_judge_passes():
    teacher = SetterSolver(SPACE, seed=1, setter_hidden_size=16)
    goals, _, success = buffer()
    f = torch.full((len(goals), 1), 0.99)
    z = torch.randn(len(goals), 2, generator=torch.Generator().manual_seed(4))

    def judged() -> float:
        with torch.no_grad():
            return float(teacher.judge(teacher.setter.sample(z, f)[0]).mean())

    before = judged()
    step_on(teacher, "feasibility", goals, f, success)
    assert judged() > before


def test_validity_step_makes_achieved_goals_likelier():
    teacher = SetterSolver(SPACE, seed=1, setter_hidden_size=16, setter_loss_noise_ub=0.0)
    goals, f, success = buffer()
    ok = success[:, 0] > 0

    def likelihood() -> float:
        with torch.no_grad():
            return float(teacher.setter.log_prob(goals[ok], f[ok]).mean())

    before = likelihood()
    step_on(teacher, "validity", goals, f, success)
    assert likelihood() > before


def test_coverage_step_raises_the_entropy_of_the_goals():
    teacher = SetterSolver(SPACE, seed=2, setter_hidden_size=16)
    gen = torch.Generator().manual_seed(3)
    z, f = torch.randn(2000, 2, generator=gen), torch.rand(2000, 1, generator=gen)

    def entropy() -> float:
        with torch.no_grad():
            return float(-teacher.setter.sample(z, f)[1].mean())

    before = entropy()
    step_on(teacher, "coverage", *buffer())
    assert entropy() > before


def test_validity_needs_an_achieved_goal():
    teacher = SetterSolver(SPACE, seed=0, setter_hidden_size=16)
    goals, f, success = buffer()
    losses = teacher.setter_losses(goals, f, torch.zeros_like(success))
    assert float(losses["validity"]) == 0.0 and not losses["validity"].requires_grad
    assert float(teacher.setter_losses(goals, f, success)["validity"].detach()) != 0.0


def test_feasibility_is_drawn_per_goal_and_kept_with_it():
    teacher = SetterSolver(SPACE, seed=0, setter_hidden_size=16, update_frequency=1000)
    tasks = [teacher.sample_task() for _ in range(50)]
    for task in tasks:
        teacher.episodic_update(task, 0.0, False)
    f = np.array([b[1] for b in teacher._buffer])
    assert len(f) == 50 and len(np.unique(f)) == 50
    assert f.min() > 0.0 and f.max() < 1.0
    assert abs(f.mean() - 0.5) < 0.15  # U(0, 1)


def test_judge_is_trained_on_the_raw_labels():
    """As in TeachMyAgent: cross-entropy against the successes as they came (here 1 of 10), not
    rebalanced between successes and failures."""
    teacher = SetterSolver(SPACE, seed=0, setter_hidden_size=16, update_frequency=10)
    tasks = [teacher.sample_task() for _ in range(10)]
    for i, task in enumerate(tasks[:9]):
        teacher.episodic_update(task, 0.0, i == 0)
    goals = torch.as_tensor(
        np.clip(
            [b[0] for b in teacher._buffer] + [teacher._pending.items()[0][1][0]], 1e-4, 1 - 1e-4
        ),
        dtype=torch.float32,
    )
    labels = torch.zeros(10, 1)
    labels[0] = 1.0
    with torch.no_grad():
        expected = float(F.binary_cross_entropy_with_logits(teacher.judge(goals), labels))
    teacher.episodic_update(tasks[9], 0.0, False)
    assert teacher.bk["judge_loss"] == [expected]
