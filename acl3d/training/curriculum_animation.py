"""The curriculum of a run as an animation: sampled tasks over training, with the teacher's state.

Each frame shows the training tasks of one window of episodes (from `episodes.csv`, coloured by
return) over the teacher's state when the window began, rebuilt from the history the teacher
keeps in its book-keeping (`teacher.json/.npz`): the fitted mixtures of ALP-GMM and Covar-GMM,
RIAC's regions (each coloured by its ALP when it was split off), ADR's box and SPDL's Gaussian.
Other teachers (and runs with shuffled dimensions, whose teacher works in another space) get
the tasks only. Drawing reuses `acl3d.teachers.plots.render_frame`, as the toy GIFs do.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from acl3d.run_format.tables import read_csv
from acl3d.teachers.plots import render_frame
from acl3d.training.run_dir import RunDir
from acl3d.video import open_sink

_EPISODE_COLUMNS = {"step", "worker", "return", "length", "success", "truncated"}


def _gmm_states(bk: dict, dim: int, by_alp: bool) -> list[tuple[int, dict]]:
    """The mixtures over [task, extra columns] cut to the task; ALP-GMM's colour is its ALP (the
    last column, as it samples), the other mixtures' their weights."""
    states = []
    for e, m, c, w in zip(bk["episodes"], bk["means"], bk["covariances"], bk["weights"]):
        m, c = np.asarray(m, dtype=np.float64), np.asarray(c, dtype=np.float64)
        weights = np.maximum(m[:, -1], 0.0) if by_alp else np.asarray(w, dtype=np.float64)
        states.append(
            (
                int(e),
                {
                    "kind": "gmm",
                    "means": m[:, :dim],
                    "covariances": c[:, :dim, :dim],
                    "weights": weights,
                    "label": "ALP" if by_alp else "Gaussian weight",
                },
            )
        )
    return states


def _riac_states(bk: dict, low: np.ndarray, high: np.ndarray) -> list[tuple[int, dict]]:
    """Replay RIAC's splits (node, dim, threshold, ALP left, ALP right) from the root box."""
    boxes = [(low.copy(), high.copy(), 0.0)]
    leaves = {0}
    states = []
    for episode, (node, dim, thr, alp_l, alp_r) in zip(bk["split_iterations"], bk["splits"]):
        node, dim = int(node), int(dim)
        box_low, box_high, _ = boxes[node]
        left_high, right_low = box_high.copy(), box_low.copy()
        left_high[dim] = right_low[dim] = float(thr)
        boxes += [(box_low, left_high, float(alp_l)), (right_low, box_high, float(alp_r))]
        leaves = (leaves - {node}) | {len(boxes) - 2, len(boxes) - 1}
        states.append(
            (int(episode), {"kind": "boxes", "boxes": [boxes[i] for i in sorted(leaves)]})
        )
    return states


def _adr_states(bk: dict) -> list[tuple[int, dict]]:
    return [
        (int(e), {"kind": "box", "low": np.asarray(lo), "high": np.asarray(hi)})
        for e, (lo, hi) in zip(bk["episodes"], bk["task_space"])
    ]


def _spdl_states(bk: dict, steps: np.ndarray) -> list[tuple[int, dict]]:
    """SPDL counts environment steps: its updates are placed at the first episode after them."""
    return [
        (
            int(np.searchsorted(steps, s, side="right")),
            {"kind": "gaussian", "mean": np.asarray(m), "covariance": np.asarray(c)},
        )
        for s, m, c in zip(bk["steps"], bk["mean"], bk["covariance"])
    ]


def teacher_states(dump: dict, steps: np.ndarray) -> list[tuple[int, dict]]:
    """[(episodes seen when the state was set, plot_state dict)] in time order, or []."""
    bk = dump.get("teacher_bk") or {}
    if dump.get("shuffled"):
        return []
    low, high = np.asarray(dump["low"], float), np.asarray(dump["high"], float)
    if bk.get("means") and bk.get("covariances"):
        return _gmm_states(bk, len(low), dump.get("teacher") == "alp-gmm")
    if bk.get("splits"):
        return _riac_states(bk, low, high)
    if bk.get("task_space"):
        return _adr_states(bk)
    if bk.get("mean") and bk.get("covariance"):
        return _spdl_states(bk, steps)
    return []


def curriculum_frames(run_dir, frames: int = 40) -> tuple[list[dict], dict]:
    """Frames for `render_frame` (windows of episodes) and facts (names, bounds, teacher)."""
    if not isinstance(frames, int) or isinstance(frames, bool) or frames < 1:
        raise ValueError(f"frames={frames!r}; valid: an integer >= 1")
    run = RunDir(run_dir)
    config = run.read_config()
    cols = read_csv(run.episodes_csv) if run.episodes_csv.exists() else {}
    if not cols.get("step"):
        raise ValueError(f"run directory {str(run.path)!r} has no training episodes yet")
    names = [k for k in cols if k not in _EPISODE_COLUMNS]
    tasks = np.column_stack([cols[n] for n in names])
    steps = np.asarray(cols["step"], dtype=np.int64)
    returns = np.asarray(cols["return"], dtype=np.float64)
    dump = _teacher_dump(run)
    if dump is not None:
        low, high = np.asarray(dump["low"], float), np.asarray(dump["high"], float)
    else:
        low, high = tasks.min(axis=0), tasks.max(axis=0)
    states = teacher_states(dump, steps) if dump is not None else []
    every = max(1, -(-len(steps) // frames))
    out = []
    for start in range(0, len(steps), every):
        end = min(start + every, len(steps))
        current = [s for e, s in states if e <= start]  # the state that sampled this window
        out.append(
            {
                "episode": end,
                "step": int(steps[end - 1]),
                "state": current[-1] if current else None,
                "tasks": tasks[start:end],
                "values": returns[start:end],
                "value_range": (float(returns.min()), float(returns.max())),
                "value_label": "episode return",
            }
        )
    facts = {
        "names": names,
        "low": low,
        "high": high,
        "teacher": config.get("teacher", "?"),
        "name": run.path.name,
    }
    return out, facts


def _teacher_dump(run: RunDir) -> dict | None:
    if not run.teacher_prefix.with_suffix(".json").exists():
        return None
    from acl3d.teachers.base import load_state

    return load_state(run.teacher_prefix)


def write_curriculum_animation(
    run_dir, out, frames: int = 40, fps: int = 4, fmt: str | None = None
) -> Path:
    """An mp4/gif (or PNG strip) of the run's curriculum; returns the path written."""
    frame_dicts, facts = curriculum_frames(run_dir, frames)
    sink = open_sink(out, fps, fmt, strip_frames=min(len(frame_dicts), 8))
    labels = facts["names"][:2] if len(facts["names"]) >= 2 else [facts["names"][0], ""]
    try:
        for frame in frame_dicts:
            title = f"{facts['name']} ({facts['teacher']}) | step {frame['step']:,} | "
            sink.append(render_frame(frame, facts["low"], facts["high"], labels, title))
    finally:
        sink.close()
    return Path(out)
