"""A teacher's plot states over a run, rebuilt from the book-keeping it dumps (`Teacher.dump`).

Each function turns one kind of book-keeping into [(episodes seen when the state was set,
plot_state dict)] in time order, in the `plot_state` protocol of `acl3d.teachers.plots`. The
teachers that keep such a history declare which function reads theirs
(`Teacher.plot_history`), so tools that animate a run never need to know the teacher.
"""

from __future__ import annotations

import numpy as np

History = list[tuple[int, dict]]


def mixtures(bk: dict, dim: int, by_alp: bool) -> History:
    """The fitted mixtures over [task, extra columns] cut to the task; coloured by their ALP
    (the last column, as ALP-GMM samples) when `by_alp`, else by their weights."""
    states = []
    if not (bk.get("means") and bk.get("covariances")):
        return states
    for e, m, c, w in zip(bk["episodes"], bk["means"], bk["covariances"], bk["weights"]):
        m, c = np.asarray(m, dtype=np.float64), np.asarray(c, dtype=np.float64)
        weights = np.maximum(m[:, -1], 0.0) if by_alp else np.asarray(w, dtype=np.float64)
        state = {
            "kind": "gmm",
            "means": m[:, :dim],
            "covariances": c[:, :dim, :dim],
            "weights": weights,
            "label": "ALP" if by_alp else "Gaussian weight",
        }
        states.append((int(e), state))
    return states


def splits(bk: dict, low: np.ndarray, high: np.ndarray) -> History:
    """The leaves after each split (node, dim, threshold, ALP left, ALP right) replayed from the
    root box [low, high]; each leaf coloured by its ALP when it was split off."""
    boxes = [(low.copy(), high.copy(), 0.0)]
    leaves = {0}
    states = []
    for episode, (node, dim, thr, alp_l, alp_r) in zip(
        bk.get("split_iterations", []), bk.get("splits", [])
    ):
        node, dim = int(node), int(dim)
        box_low, box_high, _ = boxes[node]
        left_high, right_low = box_high.copy(), box_low.copy()
        left_high[dim] = right_low[dim] = float(thr)
        boxes += [(box_low, left_high, float(alp_l)), (right_low, box_high, float(alp_r))]
        leaves = (leaves - {node}) | {len(boxes) - 2, len(boxes) - 1}
        state = {"kind": "boxes", "boxes": [boxes[i] for i in sorted(leaves)]}
        states.append((int(episode), state))
    return states


def boxes(bk: dict) -> History:
    """One box per recorded (episode, (low, high)) pair."""
    return [
        (int(e), {"kind": "box", "low": np.asarray(lo), "high": np.asarray(hi)})
        for e, (lo, hi) in zip(bk.get("episodes", []), bk.get("task_space", []))
    ]


def gaussians(bk: dict, steps: np.ndarray) -> History:
    """Gaussians recorded at environment steps, each placed at the first episode after its step
    (`steps`: the environment step at which each episode ended)."""
    return [
        (
            int(np.searchsorted(steps, s, side="right")),
            {"kind": "gaussian", "mean": np.asarray(m), "covariance": np.asarray(c)},
        )
        for s, m, c in zip(bk.get("steps", []), bk.get("mean", []), bk.get("covariance", []))
    ]
