"""Frame files: an mp4 (H.264), a looping gif, or a PNG strip (a few frames of each episode)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from acl3d.extras import optional_dependency

FORMATS = ("mp4", "gif", "png")


def _imageio():
    with optional_dependency("writing videos and PNG strips"):
        import imageio.v2 as imageio
    return imageio


def output_format(path: str | Path, fmt: str | None = None) -> str:
    """The format of `path`: `fmt` when given (it must match a known extension), else the suffix."""
    suffix = Path(path).suffix.lower().lstrip(".")
    if fmt is not None:
        if fmt not in FORMATS:
            raise ValueError(f"format={fmt!r}; valid: {', '.join(FORMATS)}")
        if suffix in FORMATS and suffix != fmt:
            raise ValueError(f"format={fmt!r} contradicts the extension of {str(path)!r}")
        return fmt
    if suffix not in FORMATS:
        raise ValueError(
            f"output path {str(path)!r}: the extension must be one of "
            f"{', '.join('.' + f for f in FORMATS)} (or pass a format)"
        )
    return suffix


def video_writer(path: str | Path, fps: int, fmt: str | None = None):
    """An imageio writer for an mp4 (ffmpeg, H.264) or a looping gif."""
    fmt = output_format(path, fmt)
    if fmt == "png":
        raise ValueError(f"{str(path)!r}: a PNG strip is not a video; use open_sink()")
    imageio = _imageio()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    if fmt == "mp4":
        return imageio.get_writer(
            path, format="FFMPEG", fps=fps, codec="libx264", quality=7, macro_block_size=8
        )
    return imageio.get_writer(path, format="GIF", mode="I", duration=1000.0 / fps, loop=0)


class VideoSink:
    """Every frame goes into the video; episode boundaries are invisible."""

    def __init__(self, path, fps: int, fmt: str | None = None):
        self.path = Path(path)
        self._writer = video_writer(path, fps, fmt)

    def append(self, frame: np.ndarray) -> None:
        self._writer.append_data(frame)

    def end_episode(self) -> None:
        pass

    def close(self) -> None:
        self._writer.close()


class StripSink:
    """A PNG with one row per episode of `per_episode` frames evenly spread over the episode.

    Episode lengths are not known in advance, so frames are kept at a stride that doubles whenever
    more than 4 x `per_episode` are held (memory stays bounded); at the episode's end the kept
    frames nearest to evenly spaced times are shown, the first and the last included.
    """

    def __init__(self, path, per_episode: int = 6):
        if not isinstance(per_episode, int) or per_episode < 1:
            raise ValueError(f"per_episode={per_episode!r}; valid: an integer >= 1")
        self.path, self.per_episode = Path(path), per_episode
        self._rows: list[np.ndarray] = []
        self._kept: list[tuple[int, np.ndarray]] = []  # (frame index in the episode, frame)
        self._stride, self._seen = 1, 0
        self._last: np.ndarray | None = None

    def append(self, frame: np.ndarray) -> None:
        self._last = frame.copy()
        if self._seen % self._stride == 0:
            self._kept.append((self._seen, self._last))
            if len(self._kept) > 4 * self.per_episode:
                self._kept, self._stride = self._kept[::2], 2 * self._stride
        self._seen += 1

    def end_episode(self) -> None:
        if not self._kept:
            return
        if self._kept[-1][0] != self._seen - 1:  # the episode's end is always shown
            self._kept.append((self._seen - 1, self._last))
        times = np.array([t for t, _ in self._kept])
        targets = np.linspace(0, self._seen - 1, self.per_episode)
        picks = dict.fromkeys(int(np.abs(times - t).argmin()) for t in targets)
        frames = [self._kept[i][1] for i in picks]
        frames += [np.zeros_like(frames[0])] * (self.per_episode - len(frames))
        self._rows.append(np.concatenate(frames, axis=1))
        self._kept, self._stride, self._seen = [], 1, 0

    def close(self) -> None:
        self.end_episode()
        if not self._rows:
            raise ValueError(f"no frames to write to {str(self.path)!r}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        _imageio().imwrite(self.path, np.concatenate(self._rows, axis=0), format="PNG")


def open_sink(path, fps: int, fmt: str | None = None, strip_frames: int = 6):
    """A VideoSink (mp4, gif) or a StripSink (png) for `path`."""
    if output_format(path, fmt) == "png":
        return StripSink(path, strip_frames)
    return VideoSink(path, fps, fmt)


def tile(frames: list[np.ndarray], cols: int) -> np.ndarray:
    """Frames of equal size in a grid of `cols` columns (missing cells black)."""
    if not frames:
        raise ValueError("tile: no frames")
    shape = frames[0].shape
    if any(f.shape != shape for f in frames):
        raise ValueError(f"tile: frames differ in size: {sorted({f.shape for f in frames})}")
    rows = -(-len(frames) // cols)
    cells = list(frames) + [np.zeros_like(frames[0])] * (rows * cols - len(frames))
    return np.concatenate(
        [np.concatenate(cells[r * cols : (r + 1) * cols], axis=1) for r in range(rows)], axis=0
    )
