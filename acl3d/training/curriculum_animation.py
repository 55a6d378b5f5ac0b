"""The curriculum of a run as an animation: sampled tasks over training, with the teacher's state.

Each frame shows the training tasks of one window of episodes (from `episodes.csv`, coloured by
return) over the teacher's state when the window began, rebuilt by the teacher class from the
history it keeps in its book-keeping (`teacher.json/.npz`, `Teacher.plot_history`): e.g. the
fitted mixtures of ALP-GMM and Covar-GMM, RIAC's regions, ADR's box and SPDL's Gaussian. Other
teachers (and runs with shuffled dimensions, whose teacher works in another space) get the tasks
only. Drawing reuses `acl3d.teachers.plots.render_frame`, as the toy GIFs do.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from acl3d.run_format.tables import read_csv
from acl3d.teachers import registered, teacher_class
from acl3d.teachers.plots import render_frame
from acl3d.training.run_dir import RunDir, read_state
from acl3d.video import open_sink

_EPISODE_COLUMNS = {"step", "worker", "return", "length", "success", "truncated"}


def teacher_states(dump: dict, steps: np.ndarray) -> list[tuple[int, dict]]:
    """[(episodes seen when the state was set, plot_state dict)] in time order, or []: what the
    dumped teacher declares it can rebuild (`Teacher.plot_history`). Only registered teachers
    are looked up (a dump never names code to import)."""
    name = dump.get("teacher")
    if dump.get("shuffled") or name not in registered():
        return []
    low, high = np.asarray(dump["low"], float), np.asarray(dump["high"], float)
    return teacher_class(name).plot_history(dump.get("teacher_bk") or {}, low, high, steps)


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
    return read_state(run.teacher_prefix)  # a damaged dump is a ValueError naming it


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
