"""Plots and a video of a run directory: what a person looks at after (or during) training.

* mastered.png   % mastered test tasks (return > the env's success return) and mean test
                 return vs training steps
* returns.png    training episode returns vs steps (raw and a moving average)
* curriculum.png sampled training tasks in the first two task dimensions, coloured by step
* final.mp4      the policy (final or latest checkpoint) on a few test tasks
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from acl3d.curriculum_profile import CurriculumProfile
from acl3d.run_format.tables import read_csv
from acl3d.training.run_dir import RunDir


def plot_mastered(run: RunDir, out: Path) -> Path | None:
    cols = read_csv(run.evals_csv) if run.evals_csv.exists() else {}
    if not cols.get("step"):
        return None
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    ax.plot(cols["step"], cols["mastered_pct"], "o-", color="tab:blue", label="% mastered")
    ax.set_xlabel("training steps")
    ax.set_ylabel("% mastered test tasks", color="tab:blue")
    ax.set_ylim(-2, 102)
    ax2 = ax.twinx()
    ax2.plot(cols["step"], cols["mean_return"], "s--", color="tab:orange", label="mean return")
    ax2.set_ylabel("mean test return", color="tab:orange")
    ax.set_title(f"{run.path.name}: evaluation")
    ax.grid(alpha=0.3)
    return _save(fig, out / "mastered.png")


def plot_returns(run: RunDir, out: Path) -> Path | None:
    cols = read_csv(run.episodes_csv) if run.episodes_csv.exists() else {}
    if not cols.get("step"):
        return None
    steps, returns = np.asarray(cols["step"]), np.asarray(cols["return"])
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    ax.plot(steps, returns, ".", alpha=0.25, markersize=3, label="episode")
    window = max(1, min(100, len(returns) // 10))
    smooth = np.convolve(returns, np.ones(window) / window, mode="valid")
    ax.plot(steps[window - 1 :], smooth, color="black", label=f"mean of {window}")
    success = _success_return(run)
    ax.axhline(success, color="tab:green", linestyle=":", label=f"success ({success:g})")
    ax.set_xlabel("training steps")
    ax.set_ylabel("training episode return")
    ax.set_title(f"{run.path.name}: training returns (tasks from the curriculum)")
    ax.legend(loc="lower right")
    ax.grid(alpha=0.3)
    return _save(fig, out / "returns.png")


def plot_curriculum(run: RunDir, out: Path) -> Path | None:
    cols = read_csv(run.episodes_csv) if run.episodes_csv.exists() else {}
    if not cols.get("step"):
        return None
    fixed = {"step", "worker", "return", "length", "success", "truncated"}
    names = [k for k in cols if k not in fixed]
    steps = np.asarray(cols["step"])
    fig = Figure(figsize=(6, 5))
    ax = fig.subplots()
    if len(names) >= 2:
        x, y = np.asarray(cols[names[0]]), np.asarray(cols[names[1]])
        ax.set_ylabel(names[1])
    else:
        x, y = np.asarray(cols[names[0]]), steps
        ax.set_ylabel("training steps")
    bounds = _teacher_bounds(run)
    if bounds is not None and len(names) >= 2:
        (x0, y0), (x1, y1) = bounds[0][:2], bounds[1][:2]
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ls="--", color="grey"))
        ax.set_xlim(x0 - 0.05 * (x1 - x0 or 1), x1 + 0.05 * (x1 - x0 or 1))
        ax.set_ylim(y0 - 0.05 * (y1 - y0 or 1), y1 + 0.05 * (y1 - y0 or 1))
    sc = ax.scatter(x, y, c=steps, cmap="viridis", s=8, alpha=0.7)
    fig.colorbar(sc, ax=ax, label="training steps")
    ax.set_xlabel(names[0])
    ax.set_title(f"{run.path.name}: sampled training tasks")
    ax.grid(alpha=0.3)
    return _save(fig, out / "curriculum.png")


def _success_return(run: RunDir) -> float:
    """The env's success return as the run's teacher dump recorded it (its curriculum profile;
    the default profile's before the first dump)."""
    path = run.teacher_prefix.with_suffix(".json")
    if path.exists():
        from acl3d.teachers.state_files import load_state

        recorded = load_state(run.teacher_prefix).get("success_return")
        if recorded is not None:
            return float(recorded)
    return CurriculumProfile().success_return


def _teacher_bounds(run: RunDir):
    """(low, high) of the teacher's task space from the run's dump, or None before the first."""
    path = run.teacher_prefix.with_suffix(".json")
    if not path.exists():
        return None
    from acl3d.teachers.state_files import load_state

    dump = load_state(run.teacher_prefix)
    return np.asarray(dump["low"]), np.asarray(dump["high"])


def _save(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)  # a bare Figure: pyplot's global state is left alone
    return path


def pick_video_tasks(tasks: np.ndarray, n: int) -> np.ndarray:
    """`n` test tasks spread from the easiest to the hardest corner (by normalised sum)."""
    tasks = np.atleast_2d(tasks)
    span = np.ptp(tasks, axis=0)
    norm = np.divide(tasks - tasks.min(axis=0), span, out=np.zeros_like(tasks), where=span > 0)
    order = np.argsort(norm.sum(axis=1), kind="stable")
    picks = np.unique(np.linspace(0, len(order) - 1, min(n, len(order))).round().astype(int))
    return tasks[order[picks]]


def write_video(
    run: RunDir,
    out: Path,
    n_tasks: int = 3,
    max_steps: int = 1000,
    every: int = 2,
    size: tuple[int, int] = (480, 320),
    seed: int = 0,
) -> tuple[Path, list[dict]]:
    """final.mp4: the deterministic policy on `n_tasks` test tasks (easy to hard), labelled.

    The same playback as `acl3d render --model RUN` (acl3d.playback).
    """
    from acl3d.playback import record_rollouts
    from acl3d.training.trained_policy import TrainedPolicy
    from acl3d.training.workers import make_env

    config = run.read_config()
    policy = TrainedPolicy(run.best_model())
    tasks = run.test_tasks()
    if tasks is None:
        raise ValueError(f"run directory {str(run.path)!r} has no teacher dump with test tasks yet")
    env_kwargs = dict(config.get("env_kwargs") or {}, width=size[0], height=size[1])
    env = make_env(config["env"], config["body"], env_kwargs, render_mode="rgb_array")
    path = out / "final.mp4"
    try:
        summaries = record_rollouts(
            env,
            policy,
            path,
            tasks=list(pick_video_tasks(tasks, n_tasks)),
            seed=seed,
            max_steps=max_steps,
            every=every,
            progress=False,
            title=f"{run.path.name} ({config.get('teacher', '?')})",
        )
    finally:
        env.close()
    return path, summaries


def write_report(run_dir, out=None, video: bool = True, **video_kwargs) -> list[Path]:
    """All plots (and the video) of a run; returns the files written."""
    run = RunDir(run_dir)
    run.read_config()  # fails clearly on a directory that is not a run
    out = Path(out) if out else run.path / "report"
    written = [
        p for p in (plot_mastered(run, out), plot_returns(run, out), plot_curriculum(run, out)) if p
    ]
    if video:
        written.append(write_video(run, out, **video_kwargs)[0])
    return written
