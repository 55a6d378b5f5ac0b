"""The curriculum profiles of the shipped environments (see `acl3d.curriculum_profile`).

Every fact a curriculum needs about Stump Tracks, Hexagon Tracks and Parkour is declared here,
next to the environments, and reaches the teachers through `env.unwrapped.curriculum_profile`:

* reward bounds for scaling: [-150, 350] on the tracks, [-150, 360] on Parkour (TeachMyAgent);
* success: a return above 230 (TeachMyAgent's threshold; also the Oracle's); ADR thresholds 0
  and 180;
* the expert-knowledge initial distributions (task-space units, diagonal "variance"):
  Stump Tracks: stump_height mean 0 (clipped into the bounds), obstacle_spacing mean = its
  maximum, any other parameter its centre, variance (0.1 * range)^2; Hexagon Tracks: mean 0
  (clipped into the bounds), variance 0.01; Parkour: none;
* test sets: the fixed Stump Tracks grid (stump_height in [0, 3] x obstacle_spacing in [0, 6])
  is the default for the 2-D stump space; Parkour names its walking, climbing and swimming sets.
* the easy side of each parameter: its lower bound, except Stump Tracks' obstacle_spacing
  (wide gaps are easy; teachDeepRL's oracle walks it downwards) and 3D Terrain's
  `EASY_AT_HIGH` parameters;
* 3D Terrain: the success flag is crossing the finish line (returns of crossings are ~250-330);
  the prior is centred on the easy corner (no blocks, no slopes, widest spacing), variance
  (0.1 * range)^2; the "graded" test set runs from flat ground to the hardest corner.
"""

from __future__ import annotations

import functools

import numpy as np

from acl3d.curriculum_profile import CurriculumProfile
from acl3d.envs import REWARD_THRESHOLD
from acl3d.task_space import TaskSpace
from acl3d.terrain import parkour_test_sets, terrain3d_test_sets


def _stump_initial_dist(space: TaskSpace) -> dict[str, np.ndarray]:
    low, high = space.low, space.high
    mean = (low + high) / 2
    if "stump_height" in space.names:
        sl = space.slice("stump_height")
        mean[sl] = np.clip(0.0, low[sl], high[sl])
    if "obstacle_spacing" in space.names:
        sl = space.slice("obstacle_spacing")
        mean[sl] = high[sl]
    return {"mean": mean, "variance": np.diag((0.1 * (high - low)) ** 2)}


def _hexagon_initial_dist(space: TaskSpace) -> dict[str, np.ndarray]:
    return {
        "mean": np.clip(0.0, space.low, space.high),
        "variance": np.diag(np.full(space.dim, 0.01)),
    }


STUMP_TRACKS = CurriculumProfile(
    name="stump-tracks",
    reward_bounds=(-150.0, 350.0),
    success_return=REWARD_THRESHOLD,
    initial_dist=_stump_initial_dist,
    default_test_grid={"stump_height": (0.0, 3.0), "obstacle_spacing": (0.0, 6.0)},
    easy_at_high=frozenset({"obstacle_spacing"}),
)

HEXAGON_TRACKS = CurriculumProfile(
    name="hexagon-tracks",
    reward_bounds=(-150.0, 350.0),
    success_return=REWARD_THRESHOLD,
    initial_dist=_hexagon_initial_dist,
)

PARKOUR = CurriculumProfile(
    name="parkour",
    reward_bounds=(-150.0, 360.0),
    success_return=REWARD_THRESHOLD,
    test_sets={
        name: functools.partial(parkour_test_sets.build, name)
        for name in (*parkour_test_sets.SEEDS, *parkour_test_sets.ALIASES)
    },
)


def _terrain3d_initial_dist(space: TaskSpace) -> dict[str, np.ndarray]:
    return {
        "mean": terrain3d_test_sets.easy_corner(space),
        "variance": np.diag((0.1 * (space.high - space.low)) ** 2),
    }


TERRAIN3D = CurriculumProfile(
    name="terrain3d",
    reward_bounds=(-150.0, 350.0),
    success_return=REWARD_THRESHOLD,
    initial_dist=_terrain3d_initial_dist,
    test_sets={"graded": terrain3d_test_sets.graded},
    easy_at_high=frozenset(terrain3d_test_sets.EASY_AT_HIGH),
)
