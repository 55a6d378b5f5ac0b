"""What each teacher is told about an environment, by expert-knowledge level.

TeachMyAgent hands out prior knowledge inconsistently (reference §1.5 and §6.9: SPDL gets its
initial distribution only under "original", ALP-GMM only under "high", ADR/GoalGAN/Setter-Solver
crash under "no"). acl3d separates two things:

* Facts of the environment, given at every level: the binary success signal (return > 230 on
  the shipped tracks and Parkour), the mean return that moves the Oracle's window on (the same
  success return), the reward thresholds ADR expands or shrinks its box with (0 and 180) and
  the easy side of each parameter (where the Oracle's window, ADR's box and GoalGAN's first
  goals start: the papers start from easy tasks, not from expert knowledge). A
  curriculum that cannot see whether an episode succeeded cannot run at all, so these are
  not "expert knowledge".
* Expert knowledge proper, the *initial distribution* (where the easy tasks are), given only at
  level "high", to every teacher that can use one:

  | teacher                 | no / low                                   | high                        |
  |-------------------------|--------------------------------------------|-----------------------------|
  | random, riac            | nothing                                    | nothing                     |
  | alp-gmm, covar-gmm      | uniform bootstrap                          | bootstrap from initial_dist |
  | adr                     | thresholds 0/180, starts at the easy task  | + starts at initial mean    |
  | self-paced              | initial dist: random mean, std 10% range   | initial_dist                |
  | goal-gan                | pretrained around the easy task (std 10%)  | pretrained on initial_dist  |
  | setter-solver           | success signal                             | same                        |
  | oracle, lessons         | hand-designed by nature (their own params) | same                        |

  "no" and "low" therefore give the same arguments: everything TeachMyAgent's "low" added is an
  environment fact here. TeachMyAgent's random starts of ADR and GoalGAN remain available as
  `start="random"` / `pretrain_around="random"`. Both names are kept so results line up with TeachMyAgent's tables.
  SPDL's target distribution is never given (no environment defines one; its default is the
  broad Gaussian over the whole space).

The facts themselves (success threshold, ADR thresholds, initial distribution) are declared by
each environment in its `CurriculumProfile` (acl3d.envs.profiles for the shipped ones); each
teacher declares which of them it takes (`Teacher.run_params`, `uses_initial_dist`); this
module gathers them.
"""

from __future__ import annotations

from typing import Any

from acl3d.curriculum_profile import CurriculumProfile
from acl3d.teachers import RunFacts, registered, teacher_class

LEVELS: tuple[str, ...] = ("no", "low", "high")


def expert_knowledge(
    profile: CurriculumProfile | None, task_space, level: str, total_steps: int | None = None
) -> dict[str, dict[str, Any]]:
    """Constructor keyword arguments for every registered teacher at expert-knowledge `level`,
    from the environment's `profile` (None: an environment that declares nothing) and the
    run's budget; each teacher declares what it takes (`Teacher.run_params`)."""
    return {
        name: teacher_params(name, profile, task_space, level, total_steps) for name in registered()
    }


def teacher_params(
    teacher: str,
    profile: CurriculumProfile | None,
    task_space,
    level: str,
    total_steps: int | None = None,
) -> dict[str, Any]:
    """Constructor keyword arguments for `teacher` (see `expert_knowledge`)."""
    if level not in LEVELS:
        raise ValueError(f"expert_knowledge level must be one of {LEVELS}, got {level!r}")
    profile = profile if profile is not None else CurriculumProfile()
    dist = profile.initial_distribution(task_space) if level == "high" else None
    facts = RunFacts(profile=profile, initial_dist=dist, total_steps=total_steps)
    return dict(teacher_class(teacher).run_params(facts))


def toy_teacher_params(teacher: str, profile: CurriculumProfile, task_space) -> dict[str, Any]:
    """Constructor keyword arguments for `teacher` on a toy problem (`acl3d.toy.ToyEnv`): the
    environment facts of its `profile` that every run gets (expert knowledge "low"), and what
    the teacher declares it needs there (`Teacher.toy_params`, told the profile's prior)."""
    facts = RunFacts(profile=profile, initial_dist=profile.initial_distribution(task_space))
    own = teacher_class(teacher).toy_params(facts)
    return teacher_params(teacher, profile, task_space, "low") | dict(own)
