"""Teacher and run state as open files: a nested dict of JSON values and arrays saved as
PATH.json (the tree, each array replaced by a key) + PATH.npz (the arrays), no pickle."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def _split_arrays(obj, arrays: dict, prefix: str):
    if isinstance(obj, dict):
        return {str(k): _split_arrays(v, arrays, f"{prefix}/{k}") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_split_arrays(v, arrays, f"{prefix}/{i}") for i, v in enumerate(obj)]
    torch = sys.modules.get("torch")  # no tensor exists before torch is imported
    if torch is not None and isinstance(obj, torch.Tensor):
        obj = obj.detach().cpu().numpy()
    if isinstance(obj, np.ndarray):
        key = f"a{len(arrays)}"
        arrays[key] = obj
        return {"__array__": key}
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _join_arrays(obj, arrays):
    if isinstance(obj, dict):
        if set(obj) == {"__array__"}:
            return arrays[obj["__array__"]]
        return {k: _join_arrays(v, arrays) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_join_arrays(v, arrays) for v in obj]
    return obj


def save_state(path, state: dict) -> None:
    """Save a nested dict of JSON values and arrays as PATH.json + PATH.npz."""
    path = Path(path)
    arrays: dict[str, np.ndarray] = {}
    tree = _split_arrays(state, arrays, "")
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path.with_suffix(".npz"), **arrays)
    path.with_suffix(".json").write_text(json.dumps(tree))


def load_state(path) -> dict:
    path = Path(path)
    tree = json.loads(path.with_suffix(".json").read_text())
    with np.load(path.with_suffix(".npz"), allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    return _join_arrays(tree, arrays)
