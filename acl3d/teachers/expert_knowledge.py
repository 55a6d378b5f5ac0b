"""What each teacher is told about an environment, by expert-knowledge level.

TeachMyAgent hands out prior knowledge inconsistently (reference §1.5 and §6.9: SPDL gets its
initial distribution only under "original", ALP-GMM only under "high", ADR/GoalGAN/Setter-Solver
crash under "no"). acl3d separates two things:

* Facts of the environment, given at every level: the binary success signal (return > 230) and
  the reward thresholds ADR expands or shrinks its box with (0 and 180). A curriculum that cannot
  see whether an episode succeeded cannot run at all, so these are not "expert knowledge".
* Expert knowledge proper, the *initial distribution* (where the easy tasks are), given only at
  level "high", to every teacher that can use one:

  | teacher                 | no / low                                   | high                        |
  |-------------------------|--------------------------------------------|-----------------------------|
  | random, riac            | nothing                                    | nothing                     |
  | alp-gmm, covar-gmm      | uniform bootstrap                          | bootstrap from initial_dist |
  | adr                     | thresholds 0/180, starts at a random task  | + starts at initial mean    |
  | self-paced              | initial dist: random mean, std 10% range   | initial_dist                |
  | goal-gan                | pretrained on a random Gaussian (std 10%)  | pretrained on initial_dist  |
  | setter-solver           | success signal                             | same                        |
  | oracle, lessons         | hand-designed by nature (their own params) | same                        |

  "no" and "low" therefore give the same arguments: everything TeachMyAgent's "low" added is an
  environment fact here. Both names are kept so results line up with TeachMyAgent's tables.
  SPDL's target distribution is never given (no environment defines one; its default is the
  broad Gaussian over the whole space).

The initial distributions (task-space units, covariance "variance" as TeachMyAgent names it):
* Stump Tracks: stump_height mean 0 (clipped into the bounds), obstacle_spacing mean = its maximum,
  any other parameter its centre; variance (0.1 * range)^2 per dimension, diagonal.
* Hexagon Tracks: mean 0 (clipped into the bounds), variance 0.01 per dimension.
* Parkour and other environments: none, so "high" adds nothing.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from acl3d.task_space import TaskSpace

LEVELS = ("no", "low", "high")
ADR_REWARD_THRESHOLDS = (0.0, 180.0)
_KNOWN_ENVS = {
    "stumptracks": "stump-tracks",
    "hexagontracks": "hexagon-tracks",
    "parkour": "parkour",
}
_TEACHERS = (
    "random",
    "alp-gmm",
    "covar-gmm",
    "riac",
    "adr",
    "self-paced",
    "goal-gan",
    "setter-solver",
    "oracle",
    "lessons",
)


def canonical_env_name(env_name: str | None) -> str | None:
    """ "acl3d/StumpTracks-v0", "stump_tracks", "stump-tracks" -> "stump-tracks"; unknown names
    come back lower-cased (they simply get no environment-specific knowledge)."""
    if env_name is None:
        return None
    base = str(env_name).split("/")[-1]
    base = re.sub(r"-v\d+$", "", base)
    key = re.sub(r"[^a-z0-9]", "", base.lower())
    return _KNOWN_ENVS.get(key, base.lower())


def initial_dist(env_name: str | None, task_space) -> dict[str, np.ndarray] | None:
    """The environment's easy-task Gaussian {"mean": (d,), "variance": (d, d)}, or None."""
    space = TaskSpace.coerce(task_space)
    env = canonical_env_name(env_name)
    low, high = space.low, space.high
    if env == "stump-tracks":
        mean = (low + high) / 2
        for name, value in (("stump_height", 0.0), ("obstacle_spacing", None)):
            if name in space.names:
                sl = space.slice(name)
                mean[sl] = high[sl] if value is None else np.clip(value, low[sl], high[sl])
        variance = np.diag((0.1 * (high - low)) ** 2)
    elif env == "hexagon-tracks":
        mean = np.clip(0.0, low, high)
        variance = np.diag(np.full(space.dim, 0.01))
    else:
        return None
    return {"mean": mean, "variance": variance}


def expert_knowledge(env_name: str | None, task_space, level: str) -> dict[str, dict[str, Any]]:
    """Constructor keyword arguments for every registered teacher at expert-knowledge `level`."""
    if level not in LEVELS:
        raise ValueError(f"expert_knowledge level must be one of {LEVELS}, got {level!r}")
    dist = initial_dist(env_name, task_space) if level == "high" else None
    with_dist = {} if dist is None else {"initial_dist": dist}
    kwargs: dict[str, dict[str, Any]] = {name: {} for name in _TEACHERS}
    kwargs["alp-gmm"] = dict(with_dist)
    kwargs["covar-gmm"] = dict(with_dist)
    kwargs["adr"] = {
        "min_reward_thr": ADR_REWARD_THRESHOLDS[0],
        "max_reward_thr": ADR_REWARD_THRESHOLDS[1],
        **with_dist,
    }
    kwargs["self-paced"] = dict(with_dist)
    kwargs["goal-gan"] = {"use_pretrained_samples": True, **with_dist}
    return kwargs
