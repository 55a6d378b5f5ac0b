"""Text labels burnt into video frames: a dimmed box with a few lines of text in a corner.

Pillow (installed with matplotlib) draws each character once per size; lines are assembled from
those cached glyphs and blended into the frame with integer numpy arithmetic, so a label costs
a fraction of a millisecond on a 640x480 frame (`scripts/bench_render.py` measures it).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import lru_cache

import numpy as np

from acl3d.extras import optional_dependency

PADDING = 4
DIM_256 = 115  # the label box keeps 115/256 (45%) of the picture's brightness behind the text


@lru_cache(maxsize=8)
def _font(size: int):
    with optional_dependency("labelled frames"):
        from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # Pillow built without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def font_size_for(height: int) -> int:
    """A readable text size for frames `height` pixels tall (10 px up to 300, 16 px at 480)."""
    return int(np.clip(round(height / 30), 10, 28))


@lru_cache(maxsize=2048)
def _glyph(char: str, size: int) -> tuple[np.ndarray, int]:
    """One character's coverage (0..255) on a full line height, and its advance in pixels."""
    from PIL import Image, ImageDraw, ImageFont

    font = _font(size)
    scalable = isinstance(font, ImageFont.FreeTypeFont)  # the bitmap font has no metrics
    ascent, descent = font.getmetrics() if scalable else (size, size // 4)
    advance = max(1, round(font.getlength(char)))
    image = Image.new("L", (max(advance, font.getbbox(char)[2], 1), ascent + descent), 0)
    ImageDraw.Draw(image).text((0, 0), char, fill=255, font=font)
    return np.asarray(image), advance


def _line_mask(text: str, size: int) -> np.ndarray:
    """A line of text from cached glyphs: Pillow draws each character once per size."""
    glyphs = [_glyph(char, size) for char in text]
    width = sum(advance for _, advance in glyphs) + max(m.shape[1] for m, _ in glyphs)
    mask = np.zeros((glyphs[0][0].shape[0], width), dtype=np.uint8)
    x = 0
    for glyph, advance in glyphs:
        target = mask[:, x : x + glyph.shape[1]]
        np.maximum(target, glyph, out=target)
        x += advance
    return mask[:, : x + 1]


def _advance(text: str, size: int) -> int:
    return sum(_glyph(char, size)[1] for char in text)


def wrap_line(text: str, size: int, max_width: int) -> list[str]:
    """`text` cut between words into lines no wider than `max_width` pixels at font `size` (a
    single word wider than that keeps its own line and is clipped at the frame's edge)."""
    lines: list[str] = []
    for word in text.split(" "):
        if lines and _advance(f"{lines[-1]} {word}", size) <= max_width:
            lines[-1] = f"{lines[-1]} {word}"
        elif word:  # the empty words of a run of spaces start no line of their own
            lines.append(word)
    return lines


def draw_label(
    frame: np.ndarray, lines: Sequence[str], size: int | None = None, corner: str = "top-left"
) -> np.ndarray:
    """Draw `lines` in a dimmed box in a corner of `frame` (H, W, 3 uint8), in place; returns it.
    A line wider than the frame wraps between words (a task's parameters all stay visible)."""
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(
            f"frame: expected an (H, W, 3) uint8 array, got {frame.shape} {frame.dtype}"
        )
    if corner not in ("top-left", "bottom-left"):
        raise ValueError(f"corner={corner!r}; valid: 'top-left', 'bottom-left'")
    if size is not None and (not isinstance(size, int) or isinstance(size, bool) or size < 4):
        raise ValueError(f"size={size!r}; valid: an integer >= 4 (pixels)")
    size = size or font_size_for(frame.shape[0])
    fitting = [
        part
        for line in lines
        if line
        for part in wrap_line(line, size, frame.shape[1] - 2 * PADDING)
    ]
    masks = [_line_mask(line, size) for line in fitting]
    if not masks:
        return frame
    line_h = max(m.shape[0] for m in masks) + 2
    width = min(frame.shape[1], max(m.shape[1] for m in masks) + 2 * PADDING)
    height = min(frame.shape[0], line_h * len(masks) + 2 * PADDING)
    top = 0 if corner == "top-left" else frame.shape[0] - height
    region = frame[top : top + height, :width]
    coverage = np.zeros(region.shape[:2], dtype=np.uint16)
    for i, mask in enumerate(masks):
        y = PADDING + i * line_h
        m = mask[: max(0, height - y), : max(0, width - PADDING)]
        coverage[y : y + m.shape[0], PADDING : PADDING + m.shape[1]] = m
    dimmed = (region.astype(np.uint16) * DIM_256) >> 8  # integer blend: 10x faster than float
    region[:] = dimmed + (((255 - dimmed) * coverage[..., None]) >> 8)
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


OUTCOMES = ("", "success", "failed", "time limit")  # running, and how an episode ended


def episode_lines(
    title: str, task, step: int, episode_return: float, outcome: str = ""
) -> list[str]:
    """The standard playback label: title, task parameters, step, return and the outcome: ""
    while running, "success", "failed" (the episode terminated without success) or "time limit"
    (stopped by a step limit before either)."""
    if outcome not in OUTCOMES:
        raise ValueError(f"outcome={outcome!r}; valid: {', '.join(map(repr, OUTCOMES))}")
    status = outcome
    return [
        title,
        format_task(task),
        f"step {step:4d}   return {episode_return:7.1f}   {status}".rstrip(),
    ]
