"""Values of `acl3d train`'s options written as text: counts such as 2e6, KEY=VALUE pairs,
bounds, and a `--config` file (YAML or TOML) holding any of them."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import yaml

from acl3d import validation as check

# config fields that are mappings -> their repeatable option
MAPPING_OPTIONS = {
    "env_kwargs": "--env-kwarg",
    "student_params": "--student-param",
    "teacher_params": "--teacher-param",
    "bounds": "--bounds",
}
# options that are counts (a config file's YAML reads 2e6 as a string)
COUNT_OPTIONS = (
    "steps", "reset_student_every", "buffer_size", "eval_every", "checkpoint_every",
    "periodical_samples_every",
)  # fmt: skip


def seed_option(value, flag: str = "--seed") -> None:
    """A seed typed on the command line: None, or an integer in [0, MAX_SEED] named as typed
    (numpy's own error names no option)."""
    from acl3d.training.config import MAX_SEED  # torch-free

    if value is not None:
        check.integer(flag, value, 0, MAX_SEED)


def count(text: str) -> int:
    """Integers written as 2e6 or 2000000."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number like 2e6, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number like 2e6, got {text!r}")
    if value != int(value):
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}")
    return int(value)


def key_values(items, what: str) -> dict:
    out = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"{what}: expected KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise ValueError(f"{what}: {item!r} has a value that is not valid YAML") from None
    return out


def parse_bounds(items) -> dict[str, list[float]]:
    out = {}
    for item in items or ():
        name, sep, rest = item.partition("=")
        parts = rest.split(",")
        try:
            values = [float(v) for v in parts]
        except ValueError:
            values = []
        if not sep or len(values) != 2:
            raise ValueError(
                f"--bounds: expected NAME=MIN,MAX (e.g. stump_height=0,9), got {item!r}"
            )
        out[name.strip()] = values
    return out


def load_config_file(path) -> dict:
    path = Path(path)
    if not path.exists():
        raise ValueError(f"--config file {str(path)!r} does not exist")
    if path.suffix.lower() == ".toml":
        try:
            import tomllib
        except ImportError:  # Python 3.10
            raise ValueError("TOML config files need Python >= 3.11; use YAML instead") from None

        parse, errors = tomllib.loads, tomllib.TOMLDecodeError
    else:
        parse, errors = yaml.safe_load, yaml.YAMLError
    try:
        data = parse(path.read_text()) or {}
    except (errors, OSError, UnicodeDecodeError) as exc:
        where = " ".join(str(exc).split())  # the parser's position, on one line
        raise ValueError(f"--config file {str(path)!r} cannot be read: {where}") from None
    if not isinstance(data, dict):
        raise ValueError(f"--config file {str(path)!r} must hold a mapping of options")
    if isinstance(data.get("config"), dict) and "environment" in data:
        # a run's config.yaml: its recipe, trained again wherever --out says, not in the run
        data = {k: v for k, v in data["config"].items() if k != "out"}
    options = {k.replace("-", "_"): v for k, v in data.items()}
    for key in MAPPING_OPTIONS:  # merged with the repeatable options: checked here
        if key in options and not isinstance(options[key], dict):
            where = f"--config file {str(path)!r}"
            raise ValueError(f"{where}: {check.fail(key, options[key], 'a mapping of names')}")
    for key in COUNT_OPTIONS:  # YAML reads 2e6 as a string
        if isinstance(options.get(key), str):
            try:
                options[key] = count(options[key])
            except argparse.ArgumentTypeError as exc:
                raise ValueError(f"--config {key}: {exc}") from None
    return options
