"""RIAC (Baranes & Oudeyer 2009): split the task space into regions of contrasting progress.

Each region of a binary tree keeps its last `max_region_size + 1` (task, return) pairs and an
absolute learning progress: the gap between the mean returns of the older and newer halves of its
last `alp_window_size` returns. A leaf that overflows is split along the cut (among
`nb_split_attempts` random ones) that best separates progress; tasks are then drawn mostly from
regions in proportion to their ALP.

Fixed bugs of the originals (TeachMyAgent / teachDeepRL), on purpose:
- split score = |ALP(left) - ALP(right)| * n_left * n_right (the originals multiply the lengths of
  two-element lists, a constant 4, so the children's balance never counted);
- new children get the ALPs of the best split (the originals gave them those of the last attempt);
- every draw uses the teacher's seeded generator (the originals' in-region draws were unseeded);
- the mutation noise is 10% of each dimension's range (the originals: 0.1 in raw units);
- only non-degenerate dimensions are split; a search that never yields a valid cut is bounded.

Kept from the originals although it looks like a detail: while no region shows progress, a region
is picked uniformly (not a uniform task), so the small regions that splits have carved out get
sampled densely; on mostly-unfeasible spaces this is what finds the learnable corner.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from acl3d import validation
from acl3d.teachers import histories
from acl3d.teachers.base import Teacher
from acl3d.teachers.gmm import pick_many, pick_proportional

P_MUTATE, P_UNIFORM = (
    0.1,
    0.2,
)  # sampling modes; the rest (0.7) is "uniform in an ALP-picked region"
MUTATION_STD = 0.1  # fraction of each dimension's range
CANDIDATE_OVERDRAW = (
    8  # random cuts drawn per attempt while looking for ones that are populated enough
)


def _window_alp(rewards: list[float], window: int) -> float:
    n = len(rewards)
    if n <= 2:
        return 0.0
    w = min(n, window)
    half = w // 2
    first = rewards[n - w : n - w + half]
    second = rewards[n - w + half :]
    return abs(sum(first) / len(first) - sum(second) / len(second))


def _masked_window_alps(mask: np.ndarray, rewards: np.ndarray, window: int) -> np.ndarray:
    """`_window_alp` of rewards[mask[c]] for every row c of a (C, n) boolean mask, vectorised."""
    n_in = mask.sum(axis=1)
    rank = np.cumsum(mask, axis=1)  # 1-based position inside the child, valid where mask
    w = np.minimum(n_in, window)
    start = (n_in - w)[:, None]
    split = start + (w // 2)[:, None]
    first = mask & (rank > start) & (rank <= split)
    second = mask & (rank > split)
    n1, n2 = first.sum(axis=1), second.sum(axis=1)
    m1 = (first @ rewards) / np.maximum(n1, 1)
    m2 = (second @ rewards) / np.maximum(n2, 1)
    return np.where(n_in > 2, np.abs(m1 - m2), 0.0)


class RIAC(Teacher):
    """Robust Intelligent Adaptive Curiosity (defaults: TeachMyAgent benchmark)."""

    name = "riac"

    @classmethod
    def plot_history(cls, bk, low, high, steps):
        """The leaf regions, replayed split by split."""
        return histories.splits(bk, low, high)

    def __init__(
        self,
        task_space,
        seed: int | None = None,
        *,
        max_region_size: int = 150,
        alp_window_size: int | None = None,
        nb_split_attempts: int = 75,
        min_region_size: float | None = None,
        min_dims_range_ratio: float = 0.1,
        discard_ratio: float = 0.25,
        sampling_in_leaves_only: bool = False,
    ):
        super().__init__(task_space, seed)
        max_region_size = validation.count("max_region_size", max_region_size, minimum=2)
        alp_window_size = max_region_size if alp_window_size is None else alp_window_size
        validation.count("alp_window_size", alp_window_size, minimum=2)
        validation.count("nb_split_attempts", nb_split_attempts)
        min_region_size = max_region_size / 20 if min_region_size is None else min_region_size
        validation.real("min_region_size", min_region_size, 0, (max_region_size + 1) / 2)
        validation.real("min_dims_range_ratio", min_dims_range_ratio, 0.0, 0.4999999)
        validation.real("discard_ratio", discard_ratio, 0.0, 1.0, exclusive_low=True)
        self.max_region_size = int(max_region_size)
        self.alp_window_size = int(alp_window_size)
        self.nb_split_attempts = int(nb_split_attempts)
        self.min_region_size = float(min_region_size)
        self.min_dims_range_ratio = float(min_dims_range_ratio)
        self.nb_discard = max(1, int(self.max_region_size * float(discard_ratio)))
        self.sampling_in_leaves_only = bool(sampling_in_leaves_only)
        self.span = self.maxs - self.mins
        self.split_dims = np.flatnonzero(self.span > 0)
        self._reset_tree()

    # ------------------------------------------------------------------ tree storage
    def _reset_tree(self) -> None:
        self.low: list[np.ndarray] = []
        self.high: list[np.ndarray] = []
        self.children: list[tuple[int, int] | None] = []
        self.cut: list[
            tuple[int, float] | None
        ] = []  # (dimension, threshold): left child is < threshold
        self.rewards: list[list[float]] = []
        self.tasks: list[list[np.ndarray]] = []
        self.alps = np.zeros(0)
        self._new_node(self.mins.copy(), self.maxs.copy(), [], [], 0.0)

    def _new_node(self, low, high, rewards, tasks, alp) -> int:
        self.low.append(low)
        self.high.append(high)
        self.children.append(None)
        self.cut.append(None)
        self.rewards.append(rewards)
        self.tasks.append(tasks)
        self.alps = np.append(self.alps, alp)
        return len(self.low) - 1

    @property
    def nb_regions(self) -> int:
        return len(self.low)

    def leaves(self) -> np.ndarray:
        return np.array([i for i, c in enumerate(self.children) if c is None], dtype=np.intp)

    # ------------------------------------------------------------------ update
    def _episodic_update(self, task: np.ndarray, reward: float, is_success: bool) -> None:
        task = self.clip(task)
        cap = self.max_region_size + 1
        node = 0
        while True:
            rewards, tasks = self.rewards[node], self.tasks[node]
            rewards.append(reward)
            tasks.append(task)
            if len(rewards) > cap:
                del rewards[0], tasks[0]
            self.alps[node] = _window_alp(rewards, self.alp_window_size)
            if self.children[node] is None:
                break
            dim, thr = self.cut[node]
            node = self.children[node][0] if task[dim] < thr else self.children[node][1]
        if len(self.rewards[node]) > self.max_region_size:
            self._split(node)

    def _split(self, node: int) -> None:
        pts = np.asarray(self.tasks[node])
        rew = np.asarray(self.rewards[node])
        low, high = self.low[node], self.high[node]
        best = None
        if len(self.split_dims):
            n_draw = self.nb_split_attempts * CANDIDATE_OVERDRAW
            dims = self.split_dims[self.rng.integers(len(self.split_dims), size=n_draw)]
            thr = low[dims] + self.rng.random(n_draw) * (high[dims] - low[dims])
            left = pts[:, dims].T < thr[:, None]  # (n_draw, n)
            n_left = left.sum(axis=1)
            populated = np.flatnonzero(
                (n_left >= self.min_region_size) & (len(rew) - n_left >= self.min_region_size)
            )
            tries = populated[: self.nb_split_attempts]
            min_width = self.min_dims_range_ratio * self.span[dims[tries]]
            wide = (thr[tries] - low[dims[tries]] >= min_width) & (
                high[dims[tries]] - thr[tries] >= min_width
            )
            tries = tries[wide]
            if len(tries):
                alp_l = _masked_window_alps(left[tries], rew, self.alp_window_size)
                alp_r = _masked_window_alps(~left[tries], rew, self.alp_window_size)
                score = np.abs(alp_l - alp_r) * n_left[tries] * (len(rew) - n_left[tries])
                b = int(score.argmax())
                best = (
                    int(dims[tries[b]]),
                    float(thr[tries[b]]),
                    left[tries[b]],
                    alp_l[b],
                    alp_r[b],
                )
        if best is None:  # no valid cut: forget the oldest pairs so the region can try again later
            del self.rewards[node][: self.nb_discard], self.tasks[node][: self.nb_discard]
            self.alps[node] = _window_alp(self.rewards[node], self.alp_window_size)
            return
        dim, thr, mask, alp_l, alp_r = best
        tasks, rewards = self.tasks[node], self.rewards[node]
        l_high, r_low = high.copy(), low.copy()
        l_high[dim] = r_low[dim] = thr
        idx_l, idx_r = np.flatnonzero(mask), np.flatnonzero(~mask)
        left_id = self._new_node(
            low.copy(), l_high, [rewards[i] for i in idx_l], [tasks[i] for i in idx_l], alp_l
        )
        right_id = self._new_node(
            r_low, high.copy(), [rewards[i] for i in idx_r], [tasks[i] for i in idx_r], alp_r
        )
        self.children[node] = (left_id, right_id)
        self.cut[node] = (dim, thr)
        # one small record per split (TMA stored every box at every split: quadratic growth)
        self.bk["split_iterations"].append(self.nb_episodes + 1)
        self.bk["splits"].append([node, dim, thr, float(alp_l), float(alp_r)])

    # ------------------------------------------------------------------ sampling
    def _region_alps(self) -> tuple[np.ndarray, np.ndarray]:
        ids = self.leaves() if self.sampling_in_leaves_only else np.arange(self.nb_regions)
        return ids, self.alps[ids]

    def _sample(self) -> np.ndarray:
        mode = self.rng.random()
        ids, alps = self._region_alps()
        if P_MUTATE <= mode < P_MUTATE + P_UNIFORM:
            return self.uniform_task()
        region = int(ids[pick_proportional(self.rng, alps)])  # uniform over regions if no ALP
        low, high = self.low[region], self.high[region]
        if mode < P_MUTATE and self.rewards[region]:
            worst = self.tasks[region][int(np.argmin(self.rewards[region]))]
            task = worst + self.rng.standard_normal(self.dim) * MUTATION_STD * self.span
            return np.clip(task, low, high)
        return self.rng.uniform(low, high)

    def _sample_batch(self, n: int) -> np.ndarray:
        """`_sample` for n tasks, each random quantity drawn for the whole batch."""
        mode = self.rng.random(n)
        ids, alps = self._region_alps()
        uniform = (P_MUTATE <= mode) & (mode < P_MUTATE + P_UNIFORM)
        tasks = np.empty((n, self.dim))
        tasks[uniform] = self.rng.uniform(self.mins, self.maxs, size=(int(uniform.sum()), self.dim))
        regions = ids[pick_many(self.rng, alps, n - int(uniform.sum()))]
        low, high = np.asarray(self.low)[regions], np.asarray(self.high)[regions]
        has_rewards = np.fromiter((len(self.rewards[r]) > 0 for r in regions), bool, len(regions))
        mutate = (mode[~uniform] < P_MUTATE) & has_rewards
        worst = np.array(  # the worst task of each mutated episode's region
            [self.tasks[r][int(np.argmin(self.rewards[r]))] for r in regions[mutate]]
        ).reshape(-1, self.dim)
        noise = self.rng.standard_normal((len(worst), self.dim)) * MUTATION_STD * self.span
        inside = np.empty((len(regions), self.dim))
        inside[mutate] = np.clip(worst + noise, low[mutate], high[mutate])
        inside[~mutate] = self.rng.uniform(low[~mutate], high[~mutate])
        tasks[~uniform] = inside
        return tasks

    def _non_exploratory_sample(self) -> np.ndarray:
        ids, alps = self._region_alps()
        region = int(ids[pick_proportional(self.rng, alps)])
        return self.rng.uniform(self.low[region], self.high[region])

    def plot_state(self) -> dict[str, Any]:
        """Every region (parents first, so children are drawn over them) with its ALP."""
        return {
            "kind": "boxes",
            "boxes": [(lo, hi, float(a)) for lo, hi, a in zip(self.low, self.high, self.alps)],
        }

    # ------------------------------------------------------------------ state
    def _extra_state(self) -> dict[str, Any]:
        sizes = [len(r) for r in self.rewards]
        return {
            "low": np.asarray(self.low),
            "high": np.asarray(self.high),
            "children": [list(c) if c is not None else None for c in self.children],
            "cut": [[c[0], c[1]] if c is not None else None for c in self.cut],
            "alps": self.alps.copy(),
            "sizes": sizes,
            "rewards": np.asarray([r for rs in self.rewards for r in rs], dtype=np.float64),
            "tasks": np.asarray([t for ts in self.tasks for t in ts], dtype=np.float64).reshape(
                -1, self.dim
            ),
        }

    def _load_extra_state(self, extra: dict[str, Any]) -> None:
        low = np.asarray(extra["low"], dtype=np.float64).reshape(-1, self.dim)
        high = np.asarray(extra["high"], dtype=np.float64).reshape(-1, self.dim)
        rewards = np.asarray(extra["rewards"], dtype=np.float64)
        tasks = np.asarray(extra["tasks"], dtype=np.float64).reshape(-1, self.dim)
        bounds = np.concatenate([[0], np.cumsum(extra["sizes"])]).astype(int)
        self.low, self.high = list(low), list(high)
        self.children = [
            tuple(int(i) for i in c) if c is not None else None for c in extra["children"]
        ]
        self.cut = [(int(c[0]), float(c[1])) if c is not None else None for c in extra["cut"]]
        self.alps = np.asarray(extra["alps"], dtype=np.float64).copy()
        self.rewards = [rewards[a:b].tolist() for a, b in zip(bounds[:-1], bounds[1:])]
        self.tasks = [list(tasks[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
