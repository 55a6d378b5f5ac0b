"""Strict argument checks shared by every layer: one place that says what a number, a count, a flag,
a seed or a numeric array is, so that every rejection reads the same.

Strict means no silent coercion: a real number is an int, a float or a numpy real scalar (never a
bool, a string or a complex); a flag is a bool (or numpy bool); a count is an int (an integral
float such as 2e6 only where the caller allows it). Non-finite values and ints too large for a
float (`10**400`) are rejected. Every failure is a `ValueError` of the form
`"{name}={value!r}; valid: {what is allowed}"`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import numpy as np

_REAL_TYPES = (int, float, np.integer, np.floating)
_MAX_SHOWN = 200  # characters of a rejected value shown in a message
MAX_NAME_BYTES = 255  # a file or folder name (one path component) on Linux and macOS
MAX_PATH_BYTES = 4095  # a whole path (Linux's PATH_MAX less its terminating byte)


def fail(name: str, value, valid: str) -> ValueError:
    """The one error format: the parameter, its value (shortened) and what is allowed."""
    shown = repr(value)
    if isinstance(value, int) and len(shown) > 40:  # 10**400 and the like
        shown = f"{shown[:12]}...({len(shown.lstrip('-'))} digits)"
    elif len(shown) > _MAX_SHOWN:
        shown = shown[: _MAX_SHOWN - 3] + "..."
    return ValueError(f"{name}={shown}; valid: {valid}")


def _number(x: float) -> str:
    """A bound as people read it: whole numbers in full (2147483647, not 2.14748e+09)."""
    if isinstance(x, int) or (math.isfinite(x) and float(x).is_integer() and abs(x) < 1e16):
        return str(int(x))
    return f"{x:g}"


def _interval(low: float, high: float) -> str:
    if low == -math.inf and high == math.inf:
        return ""
    if high == math.inf:
        return f" >= {_number(low)}"
    if low == -math.inf:
        return f" <= {_number(high)}"
    return f" in [{_number(low)}, {_number(high)}]"


def is_real(value) -> bool:
    """True for int, float and numpy real scalars; False for bools, strings, complex, arrays."""
    return isinstance(value, _REAL_TYPES) and not isinstance(value, (bool, np.bool_))


def real(
    name: str,
    value,
    low: float = -math.inf,
    high: float = math.inf,
    *,
    exclusive_low: bool = False,
) -> float:
    """A finite real number in [low, high] (or (low, high] with `exclusive_low`), as a float."""
    valid = (
        f"a finite number > {low:g}" + (f" and <= {high:g}" if high < math.inf else "")
        if exclusive_low
        else f"a finite number{_interval(low, high)}"
    )
    if not is_real(value):
        raise fail(name, value, valid)
    try:
        v = float(value)
    except OverflowError:
        raise fail(name, value, valid) from None
    if not math.isfinite(v) or v > high or v < low or (exclusive_low and v == low):
        raise fail(name, value, valid)
    return v


def positive(name: str, value, *, allow_zero: bool = False) -> float:
    """A finite number > 0 (>= 0 with `allow_zero`)."""
    if allow_zero:
        return real(name, value, 0.0)
    return real(name, value, 0.0, exclusive_low=True)


def integer(
    name: str,
    value,
    low: float = -math.inf,
    high: float = math.inf,
    *,
    allow_float: bool = False,
) -> int:
    """An int in [low, high]; with `allow_float`, an integral float (2e6) is accepted too."""
    valid = f"an integer{_interval(low, high)}"  # whole-number bounds in full
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        v = int(value)
    elif allow_float and isinstance(value, (float, np.floating)) and float(value).is_integer():
        v = int(value)
    else:
        raise fail(name, value, valid)
    if not low <= v <= high:
        raise fail(name, value, valid)
    return v


def count(name: str, value, *, minimum: int = 1, allow_float: bool = False) -> int:
    """A number of things: an int >= `minimum` (1 unless told)."""
    return integer(name, value, minimum, allow_float=allow_float)


def flag(name: str, value) -> bool:
    """A bool or numpy bool (never the string "False", never 0/1)."""
    if not isinstance(value, (bool, np.bool_)):
        raise fail(name, value, "True or False")
    return bool(value)


def optional_flag(name: str, value) -> bool | None:
    """None (a default chosen elsewhere) or a flag."""
    return None if value is None else flag(name, value)


def choice(name: str, value, valid: Sequence):
    """One of `valid` (compared by equality; strings stay strings)."""
    if isinstance(value, (list, dict, set, np.ndarray)) or value not in tuple(valid):
        raise fail(name, value, f"one of {list(valid)}")
    return value


def optional_names(name: str, value, what: str) -> tuple[str, ...] | None:
    """None (the default set) or a non-empty list or tuple of strings (`what`: which names)."""
    if value is None:
        return None
    if (
        not isinstance(value, (list, tuple))
        or not value
        or not all(isinstance(n, str) for n in value)
    ):
        raise fail(name, value, f"None or a non-empty list of {what}")
    return tuple(value)


def seed(value, name: str = "seed") -> int | None:
    """None or a non-negative int (a bool is not a seed)."""
    if value is None:
        return None
    return integer(name, value, 0)


def real_array_in(name: str, value, low: float, high: float, what: str = "values in"):
    """`real_array` whose every element lies in [low, high] (the message shows the range)."""
    arr = real_array(name, value)
    if np.any(arr < low) or np.any(arr > high):
        shown = np.round(arr, 4).tolist()
        raise fail(name, shown, f"{what} [{low:g}, {high:g}]")
    return arr


def path(name: str, value) -> str:
    """A non-empty path string the OS can take: every name in it at most 255 bytes and the whole
    at most 4095 (encoded), so that a long name is refused before anything is written."""
    valid = f"a path whose names are at most {MAX_NAME_BYTES} bytes each"
    if not isinstance(value, str) or not value:
        raise fail(name, value, valid)
    encoded = os.fsencode(value)
    longest = max(len(part) for part in encoded.split(b"/"))
    if longest > MAX_NAME_BYTES:
        raise fail(name, value, f"{valid} (one here has {longest})")
    if len(encoded) > MAX_PATH_BYTES:
        raise fail(name, value, f"a path of at most {MAX_PATH_BYTES} bytes ({len(encoded)} here)")
    return value


def only_reals(value) -> bool:
    """Recursively: only real numbers in nested lists/tuples (no bools, strings, None, complex)."""
    if isinstance(value, (list, tuple)):
        return all(only_reals(v) for v in value)
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "iuf"
    return is_real(value)


def real_array(name: str, value, *, shape: tuple[int, ...] | None = None, size: int | None = None):
    """A finite float64 array from a real scalar, a (nested) list of reals or a real numpy array.

    `shape` asks for an exact shape, `size` for a number of elements (the array is then
    flattened). Bools, strings, complex numbers and objects are rejected, not converted.
    """
    if isinstance(value, np.ndarray) and value.dtype.kind == "f" and value.shape == shape:
        arr = value.astype(np.float64)  # the env-step fast path: a float array of the right shape
    else:
        if not only_reals(value):
            raise _not_real_array(name, value, shape, size)
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (OverflowError, ValueError):  # ints beyond float range, ragged lists
            raise _not_real_array(name, value, shape, size) from None
        if size is not None:
            arr = arr.reshape(-1)
        if (shape is not None and arr.shape != tuple(shape)) or (
            size is not None and arr.size != size
        ):
            raise _not_real_array(name, value, shape, size)
    if not np.isfinite(arr).all():
        raise _not_real_array(name, value, shape, size)
    return arr


def _not_real_array(name: str, value, shape, size) -> ValueError:
    what = "finite real numbers"
    if shape is not None:
        what += f" of shape {tuple(shape)}"
    elif size is not None:
        what += f" ({size} value{'s' if size != 1 else ''})"
    return fail(name, value, what)
