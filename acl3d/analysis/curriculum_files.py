"""The files of an exported run that let others check its curriculum, each within a byte budget.

`episodes.npz` holds every training episode (compressed columns: `step` int32, `return`
float32, `length` int32, `success` and `truncated` bool, `task` float32 (n, dim), `task_names`),
so the tasks a teacher chose and how the student did on them can be followed episode by
episode. `teacher.json` + `teacher.npz` hold the teacher's dump (`Controller.dump`) in the
format `acl3d.teachers.base.load_state` reads (`read_teacher` unpacks its histories, each
stored as one array): the task space, the periodical samples of its task distribution and its
book-keeping history (`teacher_bk`: the mixtures, regions, boxes from
which `Teacher.plot_history` rebuilds its states), floats in float32, compressed; its copies of
the episodes and test results (shipped in episodes.npz and evals_tasks.csv) are left out.

A run whose file would exceed its budget keeps every k-th episode, the smallest k that fits
(`every` in episodes.npz, 1: all kept; `episodes`: how many the run played); the teacher's
histories keep at most as many entries each as fit, every k-th of a longer one (`every` in
teacher.json: {path: k} of the thinned ones). The budgets keep a 20M-step campaign of ~150
runs under ~30 MB (docs/results.md, "Size budget").
"""

from __future__ import annotations

import io
import math
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from acl3d import validation as check
from acl3d.run_format import layout
from acl3d.run_format.tables import read_csv
from acl3d.teachers.state_files import load_state, save_state

EPISODES_FILE = "episodes.npz"
EPISODES_BUDGET = 96_000  # bytes of episodes.npz per run
TEACHER_BUDGET = 48_000  # bytes of teacher.json + teacher.npz per run
RESULTS_BUDGET = 30_000_000  # bytes of every shipped protocol together (acl3d/results)
EPISODE_LOG_COLUMNS = ("step", "worker", "return", "length", "success", "truncated")
# The dump's records shipped in other files: the played episodes (episodes.npz), the tasks drawn
# for them, and the test episodes (evals_tasks.csv).
DUPLICATED_RECORDS = (
    "sampled_tasks", "train_tasks", "train_returns", "train_lengths", "train_success",
    "test_played_tasks", "test_returns", "test_lengths", "test_success",
)  # fmt: skip


def episode_columns(log: dict[str, list[float]]) -> dict[str, np.ndarray]:
    """The compact columns of an episode log read by `read_csv`."""
    names = [c for c in log if c not in EPISODE_LOG_COLUMNS]
    n = len(log.get("step", []))
    return {
        "step": np.asarray(log.get("step", []), dtype=np.int32),
        "return": np.asarray(log.get("return", []), dtype=np.float32),
        "length": np.asarray(log.get("length", []), dtype=np.int32),
        "success": np.asarray(log.get("success", []), dtype=bool),
        "truncated": np.asarray(log.get("truncated", [0] * n), dtype=bool),
        "task": np.asarray([log[c] for c in names], np.float32).reshape(len(names), n).T,
        "task_names": np.asarray(names, dtype=str),
    }


def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def _thinned(size: int, budget: int, write):
    """(every, result): `write(every)` gives (result, bytes); the smallest stride whose bytes fit
    `budget` (bytes fall as the stride grows), or `size` (one entry kept) when none does."""
    too_small, every = 0, 1
    result, used = write(every)
    while used > budget and every < size:  # grow the stride by the bytes' excess
        too_small, every = every, min(size, max(every + 1, math.ceil(every * used / budget)))
        result, used = write(every)
    if used > budget:
        return every, result
    while every - too_small > 1:  # the jumps may overshoot: halve back to the smallest
        middle = (too_small + every) // 2
        tried, used = write(middle)
        if used <= budget:
            every, result = middle, tried
        else:
            too_small = middle
    return every, result


def write_episodes(run: Path, dest: Path, budget: int = EPISODES_BUDGET) -> dict | None:
    """DEST/episodes.npz from RUN/episodes.csv; {'episodes', 'every', 'bytes'}, or None for a
    run without an episode log."""
    check.count("budget", budget)
    log_path = Path(run) / layout.EPISODES
    if not log_path.exists():
        return None
    columns = episode_columns(read_csv(log_path, strict=True))
    n = len(columns["step"])

    def write(every: int):
        kept = {k: v if k == "task_names" else v[::every] for k, v in columns.items()}
        data = _npz_bytes({**kept, "every": np.int32(every), "episodes": np.int64(n)})
        return data, len(data)

    every, data = _thinned(n, budget, write)
    (Path(dest) / EPISODES_FILE).write_bytes(data)
    return {"episodes": n, "every": every, "bytes": len(data)}


def read_episodes(run) -> dict[str, np.ndarray]:
    """The training episodes of an exported run (episodes.npz) or of a run directory
    (episodes.csv), as `episode_columns`; an exported one adds `every` and `episodes`."""
    run = Path(run)
    if (run / EPISODES_FILE).exists():
        with np.load(run / EPISODES_FILE, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    if (run / layout.EPISODES).exists():
        return episode_columns(read_csv(run / layout.EPISODES, strict=True))
    raise ValueError(f"{str(run)!r} holds neither {EPISODES_FILE} nor {layout.EPISODES}")


def _compact(value):
    """Floats in float32, integers in int32 where they fit, everywhere in a dump's tree."""
    if isinstance(value, dict):
        return {k: _compact(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_compact(v) for v in value]
    if isinstance(value, np.ndarray):
        if value.dtype.kind == "f":
            return value.astype(np.float32)
        if value.dtype.kind in "iu" and (value.size == 0 or np.abs(value).max() < 2**31):
            return value.astype(np.int32)
    return value


def _packed(sequence):
    """A history list of arrays (or of number lists) as one {'ragged': the entries concatenated,
    'offsets'} pair, one npz entry instead of one per refit (each costs ~200 bytes of headers),
    and a list of numbers as a 1-D array (JSON spends ~19 bytes on a float); other values as
    they are. `read_teacher` unpacks the pairs into lists of arrays."""
    if not isinstance(sequence, list) or not sequence:
        return sequence
    try:
        items = [np.asarray(v) for v in sequence]
    except ValueError:  # ragged nested lists
        return sequence
    if any(a.dtype.kind not in "biuf" for a in items):
        return sequence
    if all(a.ndim == 0 for a in items):  # one number per entry (an ALP, an origin)
        return _compact(np.asarray(items))
    if any(a.ndim == 0 for a in items) or len({a.shape[1:] for a in items}) != 1:
        return sequence
    offsets = np.cumsum([0, *(len(a) for a in items)])
    return _compact({"ragged": np.concatenate(items), "offsets": offsets})


def _unpacked(value):
    if isinstance(value, dict):
        if set(value) == {"ragged", "offsets"}:
            bounds = np.asarray(value["offsets"])
            return [value["ragged"][a:b] for a, b in zip(bounds[:-1], bounds[1:])]
        return {k: _unpacked(v) for k, v in value.items()}
    return value


def _histories(dump: dict) -> dict[str, list | np.ndarray]:
    """The sequences that grow with training: the periodical samples and each list (one entry
    per refit, per episode, ...) of the teacher's book-keeping, by path."""
    out = {k: dump[k] for k in ("periodical_samples", "periodical_steps") if k in dump}
    for key, value in (dump.get("teacher_bk") or {}).items():
        if isinstance(value, (list, np.ndarray)):
            out[f"teacher_bk/{key}"] = value
    return out


def _saved_files(tree: dict) -> tuple[bytes, bytes]:
    """(json, compressed npz) bytes of `save_state(tree)`."""
    with tempfile.TemporaryDirectory() as tmp:
        prefix = Path(tmp) / layout.TEACHER
        save_state(prefix, tree)
        with np.load(prefix.with_suffix(".npz"), allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        return prefix.with_suffix(".json").read_bytes(), _npz_bytes(arrays)


def write_teacher(run: Path, dest: Path, budget: int = TEACHER_BUDGET) -> dict | None:
    """DEST/teacher.json + teacher.npz, the compact dump of RUN's teacher; {'every': {path:
    stride} of the thinned sequences, 'bytes', 'left_out'}, or None for a run without a dump.
    Thinning caps the entries kept per sequence, so the longest (per-episode) lists lose
    entries first and the short ones (one entry per refit) keep them all while they fit."""
    check.count("budget", budget)
    prefix = Path(run) / layout.TEACHER
    if not prefix.with_suffix(".json").exists():
        return None
    try:
        dump = load_state(prefix)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{prefix}.json/.npz cannot be read: {exc}") from None
    left_out = sorted(k for k in DUPLICATED_RECORDS if k in dump)
    kept = _compact({k: v for k, v in dump.items() if k not in DUPLICATED_RECORDS})
    histories = _histories(kept)

    longest = max([len(v) for v in histories.values()] + [1])

    def write(every: int):
        cap = -(-longest // every)  # entries kept per sequence; sequences of a length stay aligned
        # (an empty sequence, as a short run's refits, keeps stride 1)
        strides = {path: max(1, -(-len(sequence) // cap)) for path, sequence in histories.items()}
        tree = {**kept, "teacher_bk": dict(kept.get("teacher_bk") or {})}
        for path, sequence in histories.items():
            parent, _, key = path.rpartition("/")
            (tree[parent] if parent else tree)[key] = _packed(sequence[:: strides[path]])
        thinned = {path: k for path, k in strides.items() if k > 1}
        tree.update(every=thinned, left_out=left_out, format="acl3d-teacher-export-1")
        files = _saved_files(tree)
        return (files, thinned), sum(len(f) for f in files)

    _, ((text, arrays), thinned) = _thinned(longest, budget, write)
    (Path(dest) / f"{layout.TEACHER}.json").write_bytes(text)
    (Path(dest) / f"{layout.TEACHER}.npz").write_bytes(arrays)
    return {"every": thinned, "bytes": len(text) + len(arrays), "left_out": left_out}


def read_teacher(run) -> dict:
    """An exported run's teacher dump (or a run directory's full one) as `load_state` gives it,
    its packed histories unpacked into lists of arrays."""
    prefix = Path(run) / layout.TEACHER
    if not prefix.with_suffix(".json").exists():
        raise ValueError(f"{str(run)!r} holds no {layout.TEACHER}.json")
    return _unpacked(load_state(prefix))


def shipped_bytes(folder) -> int:
    """Bytes of every file under `folder` (the size budget's measure)."""
    return sum(p.stat().st_size for p in Path(folder).rglob("*") if p.is_file())
