"""Text labels burnt into video frames: a dimmed box with a few lines of text, top-left.

Text is drawn with Pillow (already installed as a matplotlib dependency) on the label's crop
only, so a label costs a fraction of a millisecond on a 640x480 frame (see the README's numbers).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import lru_cache

import numpy as np

PADDING = 4
DIM = 0.45  # the label box keeps 45% of the picture's brightness behind the text


@lru_cache(maxsize=8)
def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # Pillow built without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def font_size_for(height: int) -> int:
    """A readable text size for frames `height` pixels tall (11 px at 240, 16 px at 480)."""
    return int(np.clip(round(height / 30), 10, 28))


def draw_label(
    frame: np.ndarray, lines: Sequence[str], size: int | None = None, corner: str = "top-left"
) -> np.ndarray:
    """Draw `lines` in a dimmed box in a corner of `frame` (H, W, 3 uint8), in place; returns it."""
    from PIL import Image, ImageDraw

    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(
            f"frame: expected an (H, W, 3) uint8 array, got {frame.shape} {frame.dtype}"
        )
    if corner not in ("top-left", "bottom-left"):
        raise ValueError(f"corner={corner!r}; valid: 'top-left', 'bottom-left'")
    lines = [line for line in lines if line]
    if not lines:
        return frame
    font = _font(size or font_size_for(frame.shape[0]))
    boxes = [font.getbbox(line) for line in lines]
    line_h = max(b[3] for b in boxes) + 2
    width = min(frame.shape[1], max(b[2] for b in boxes) + 2 * PADDING)
    height = min(frame.shape[0], line_h * len(lines) + 2 * PADDING)
    top = 0 if corner == "top-left" else frame.shape[0] - height
    region = frame[top : top + height, :width]
    region[:] = (region * DIM).astype(np.uint8)
    image = Image.fromarray(region)
    draw = ImageDraw.Draw(image)
    for i, line in enumerate(lines):
        draw.text((PADDING, PADDING + i * line_h), line, fill=(255, 255, 255), font=font)
    region[:] = np.asarray(image)
    return frame


def format_task(task: Mapping[str, float] | Sequence[float] | np.ndarray, digits: int = 2) -> str:
    """`stump_height=1.50 obstacle_spacing=3.00` (a dict) or `[1.50, 3.00]` (a vector)."""
    if isinstance(task, Mapping):
        return " ".join(f"{k}={_fmt(v, digits)}" for k, v in task.items())
    return "[" + ", ".join(f"{float(v):.{digits}f}" for v in np.ravel(task)) + "]"


def _fmt(value, digits: int) -> str:
    values = np.ravel(np.asarray(value, dtype=np.float64))
    if values.size == 1:
        return f"{values[0]:.{digits}f}"
    return "[" + ",".join(f"{v:.{digits}f}" for v in values) + "]"


def episode_lines(
    title: str, task, step: int, episode_return: float, success: bool, done: bool
) -> list[str]:
    """The standard playback label: title, task parameters, step, return and success."""
    status = ("success" if success else "failed") if done else ("success so far" if success else "")
    return [
        title,
        format_task(task),
        f"step {step:4d}   return {episode_return:7.1f}   {status}".rstrip(),
    ]
