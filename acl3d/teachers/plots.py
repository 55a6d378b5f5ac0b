"""GIFs of a teacher's sampling dynamics, drawn from a small, teacher-agnostic protocol.

A teacher may define `plot_state() -> dict | None` describing its current distribution:
  {"kind": "gmm", "means": (k, d), "covariances": (k, d, d), "weights": (k,)}  (2-sigma ellipses)
  {"kind": "boxes", "boxes": [(low, high, value), ...]}  (regions coloured by value, e.g. ALP)
  {"kind": "box", "low": (d,), "high": (d,)}  (one box: ADR's range, the oracle's window)
  {"kind": "gaussian", "mean": (d,), "covariance": (d, d)}  (1- and 2-sigma ellipses)
  {"kind": "lesson", "index": int, "tasks": (n, d)}  (a list of lessons, the current one marked)
  {"kind": "points", "points": (n, d), "values": (n,)}  (a level buffer coloured by score)
"gmm", "boxes" and "points" may carry a "label" for their colour bar.
Anything else (or no plot_state) gives a plain scatter of the sampled tasks. Frames show the first
two task dimensions (a 1-D space is drawn on a line) over an optional background grid, such as the
toy environment's competence map.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

# Every figure that compares teachers draws each one in its colour here, the same in every
# figure (a colour cycle by position gave two teachers one colour as soon as there were more
# than ten, or the same teacher another colour in another figure). Random, the usual baseline,
# is dark grey. A shipped teacher needs a line (tests/test_teacher_colors.py holds them unique).
TEACHER_COLORS: dict[str, str] = {
    "random": "#4d4d4d",
    "alp-gmm": "#1f77b4",
    "covar-gmm": "#17becf",
    "riac": "#2ca02c",
    "adr": "#ff7f0e",
    "self-paced": "#9467bd",
    "goal-gan": "#d62728",
    "setter-solver": "#8c564b",
    "oracle": "#e377c2",
    "lessons": "#bcbd22",
    "robust-plr": "#000075",
    "accel": "#800000",
    "terrain-levels": "#469990",
}
# Teachers registered outside the package: a colour none of the shipped ones has, picked by a
# stable hash of the name (the same in every figure and every run).
OTHER_COLORS = ("#f032e6", "#e0b000", "#a9a9a9", "#fb9a99", "#b2df8a")


def teacher_color(name: str) -> str:
    """The colour `name` is drawn in, in every figure."""
    if name in TEACHER_COLORS:
        return TEACHER_COLORS[name]
    return OTHER_COLORS[zlib.crc32(name.encode()) % len(OTHER_COLORS)]


class SamplingRecorder:
    """Observer for `acl3d.toy.run_teacher`: one frame per `every` episodes.

    Each frame pairs the teacher's state at the start of a window with the tasks sampled during
    it (the tasks that state generated) and their returns.
    """

    def __init__(
        self,
        teacher,
        every: int = 250,
        background: Callable[[], np.ndarray] | None = None,
        background_extent: tuple[float, float, float, float] | None = None,
    ):
        if every < 1:
            raise ValueError(f"every must be >= 1 episode, got {every!r}")
        self.teacher, self.every, self.background = teacher, int(every), background
        self.background_extent = background_extent  # (x0, x1, y0, y1); default: the task space
        self.frames: list[dict[str, Any]] = []
        self._state = teacher.plot_state()
        self._tasks: list[np.ndarray] = []
        self._values: list[float] = []

    def __call__(self, episode: int, task, reward: float) -> None:
        self._tasks.append(np.asarray(task, dtype=np.float64))
        self._values.append(float(reward))
        if (episode + 1) % self.every == 0:
            self.frames.append(
                {
                    "episode": episode + 1,
                    "state": self._state,
                    "tasks": np.asarray(self._tasks),
                    "values": np.asarray(self._values),
                    "background": None
                    if self.background is None
                    else np.array(self.background(), dtype=np.float64),
                    "background_extent": self.background_extent,
                }
            )
            self._state = self.teacher.plot_state()
            self._tasks, self._values = [], []


def _xy(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    points = np.atleast_2d(points)
    if points.shape[1] >= 2:
        return points[:, 0], points[:, 1]
    return points[:, 0], np.full(len(points), 0.5)


def _ellipse(ax, mean, cov, n_sigma: float, **kw) -> None:
    from matplotlib.patches import Ellipse

    x, y = _xy(np.asarray(mean)[None])
    cov = np.asarray(cov, dtype=np.float64)
    cov2 = cov[:2, :2] if cov.shape[0] >= 2 else np.array([[cov[0, 0], 0.0], [0.0, 0.0]])
    vals, vecs = np.linalg.eigh(cov2)
    vals = np.maximum(vals, 0.0)
    angle = np.degrees(np.arctan2(vecs[1, -1], vecs[0, -1]))
    width, height = 2 * n_sigma * np.sqrt(vals[-1]), 2 * n_sigma * np.sqrt(vals[0])
    ax.add_patch(Ellipse((x[0], y[0]), width, height, angle=angle, **kw))


def _rect(ax, low, high, **kw) -> None:
    from matplotlib.patches import Rectangle

    (x0,), (y0,) = _xy(np.asarray(low)[None])
    (x1,), (y1,) = _xy(np.asarray(high)[None])
    if np.asarray(low).shape[0] < 2:
        y0, y1 = 0.0, 1.0
    ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, **kw))


def _draw_state(fig, ax, state: dict[str, Any] | None) -> str:
    """Draw one plot_state; returns a short title suffix."""
    import matplotlib as mpl

    if not state:
        return ""
    kind = state.get("kind")
    if kind == "gmm":
        weights = np.asarray(state["weights"], dtype=np.float64)
        norm = mpl.colors.Normalize(0.0, weights.max() if weights.max() > 0 else 1.0)
        cmap = mpl.colormaps["viridis"]
        for mean, cov, w in zip(state["means"], state["covariances"], weights):
            _ellipse(ax, mean, cov, 2.0, facecolor=cmap(norm(w)), edgecolor="k", alpha=0.6, lw=0.5)
        fig.colorbar(
            mpl.cm.ScalarMappable(norm=norm, cmap=cmap),
            ax=ax,
            label=state.get("label", "Gaussian weight"),
        )
        return f" | nb Gaussians: {len(weights)}"
    if kind == "boxes":
        boxes = state["boxes"]
        values = np.array([b[2] for b in boxes], dtype=np.float64)
        norm = mpl.colors.Normalize(0.0, values.max() if len(values) and values.max() > 0 else 1.0)
        cmap = mpl.colormaps["jet"]
        for low, high, value in boxes:
            _rect(ax, low, high, facecolor=cmap(norm(value)), edgecolor="white", lw=0.8, alpha=0.8)
        fig.colorbar(
            mpl.cm.ScalarMappable(norm=norm, cmap=cmap),
            ax=ax,
            label=state.get("label", "Absolute Learning Progress"),
        )
        return f" | {len(boxes)} regions"
    if kind == "points":
        points = np.asarray(state["points"], dtype=np.float64)
        if not len(points):
            return " | empty buffer"
        x, y = _xy(points)
        art = ax.scatter(x, y, c=state["values"], cmap="viridis", s=10, marker="s", alpha=0.7)
        fig.colorbar(art, ax=ax, label=state.get("label", "score"))
        return f" | {len(points)} levels"
    if kind == "box":
        _rect(ax, state["low"], state["high"], facecolor=(1, 0, 0, 0.15), edgecolor="red", lw=2)
        return ""
    if kind == "gaussian":
        for n_sigma, alpha in ((1.0, 0.5), (2.0, 0.25)):
            _ellipse(
                ax,
                state["mean"],
                state["covariance"],
                n_sigma,
                facecolor="tab:blue",
                edgecolor="k",
                alpha=alpha,
            )
        return ""
    if kind == "lesson":
        tasks = np.atleast_2d(np.asarray(state["tasks"], dtype=np.float64))
        x, y = _xy(tasks)
        ax.plot(x, y, "o--", color="0.4", ms=4, lw=0.8)
        i = int(state["index"])
        if 0 <= i < len(tasks):
            ax.plot(x[i], y[i], "*", color="red", ms=16, mec="k")
        return f" | lesson {i + 1}/{len(tasks)}"
    return ""


def render_frame(
    frame: dict[str, Any], low, high, labels=("task[0]", "task[1]"), title: str = ""
) -> np.ndarray:
    """One frame as an (H, W, 3) uint8 image.

    The sampled tasks are coloured by their `values` on a colour scale drawn beside the plot:
    `frame["value_range"]` (vmin, vmax) fixes it across the frames of an animation (else each
    frame spans its own values), `frame["value_label"]` names it (default "return")."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    x_lim = (low[0], high[0] if high[0] > low[0] else low[0] + 1.0)
    y_lim = (low[1], high[1] if high[1] > low[1] else low[1] + 1.0) if len(low) >= 2 else (0.0, 1.0)
    fig = Figure(figsize=(5.6, 4.8), dpi=80)  # no pyplot: leaves the user's backend alone
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    bg = frame.get("background")
    if bg is not None:
        ax.imshow(
            np.asarray(bg).T,
            origin="lower",
            extent=frame.get("background_extent") or (*x_lim, *y_lim),
            cmap="Greys",
            vmin=0,
            vmax=100,
            alpha=0.3,
            aspect="auto",
        )
    suffix = _draw_state(fig, ax, frame.get("state"))
    tasks = frame.get("tasks")
    if tasks is not None and len(tasks):
        x, y = _xy(tasks)
        values = np.asarray(frame.get("values", np.zeros(len(tasks))))
        vmin, vmax = frame.get("value_range") or (values.min(), values.max())
        art = ax.scatter(x, y, c=values, cmap="autumn_r", vmin=vmin, vmax=vmax, s=6,
                         edgecolors="none", zorder=3)  # fmt: skip
        fig.colorbar(art, ax=ax, label=frame.get("value_label", "return"))
    ax.set_xlim(*x_lim)
    ax.set_ylim(*y_lim)
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1] if len(labels) > 1 else "")
    ax.set_title(f"{title}Episode {frame['episode']}{suffix}")
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def write_gif(
    frames: list[dict[str, Any]],
    path,
    low,
    high,
    labels=("task[0]", "task[1]"),
    title: str = "",
    frame_seconds: float = 0.4,
) -> Path:
    """Render `frames` (from SamplingRecorder) into an animated GIF at `path`."""
    import imageio.v2 as imageio

    if not frames:
        raise ValueError("no frames to write: record at least `every` episodes")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    images = [render_frame(f, low, high, labels, title) for f in frames]
    imageio.mimsave(path, images, duration=frame_seconds * 1000, loop=0)
    return path
