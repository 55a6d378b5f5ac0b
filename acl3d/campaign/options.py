"""Training options in campaign specs and `--set KEY=VALUE`: parsed and checked against
`TrainConfig`'s fields (names and types) before any run is expanded or written."""

from __future__ import annotations

import dataclasses
from typing import Any

import yaml

from acl3d.training import TrainConfig

# Options the campaign sets itself for every run.
CAMPAIGN_OWNED = ("out", "seed")


def _field_kinds() -> dict[str, str]:
    """TrainConfig field -> 'int' | 'float' | 'bool' | 'str' | 'dict' | 'any', from its
    annotation, with ' | None' when None is allowed."""
    kinds = {}
    for f in dataclasses.fields(TrainConfig):
        annotation = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
        kind = next(
            (k for k in ("bool", "int", "float", "str", "dict") if annotation.startswith(k)), "any"
        )
        kinds[f.name] = kind + (" | None" if "None" in annotation else "")
    return kinds


def check_options(options: dict, where: str) -> None:
    """Every key a TrainConfig option the campaign does not own, every value of its type."""
    if not isinstance(options, dict):
        raise ValueError(f"{where}: expected a mapping of training options, got {options!r}")
    kinds = _field_kinds()
    for key, value in options.items():
        if key in CAMPAIGN_OWNED:
            raise ValueError(
                f"{where}: {key!r} is set by the campaign for each run (use seeds / --out)"
            )
        if key not in kinds:
            raise ValueError(
                f"{where}: unknown training option {key!r}; valid: {sorted(set(kinds) - set(CAMPAIGN_OWNED))}"
            )
        kind, _, optional = kinds[key].partition(" | ")
        if (value is None and optional) or (value is not None and _has_kind(value, kind)):
            continue
        raise ValueError(f"{where}: option {key!r} must be of type {kinds[key]}, got {value!r}")


def _has_kind(value, kind: str) -> bool:
    if kind == "bool":
        return isinstance(value, bool)
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "float":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind == "str":
        return isinstance(value, str)
    if kind == "dict":
        return isinstance(value, dict)
    return True


def parse_set(items: list[str] | None) -> dict[str, Any]:
    """`KEY=VALUE` strings -> options (VALUE read as YAML; counts may be written 2e6)."""
    kinds = _field_kinds()
    out = {}
    for item in items or ():
        key, sep, text = item.partition("=")
        key = key.strip().replace("-", "_")
        if not sep or not key:
            raise ValueError(f"--set: expected KEY=VALUE, got {item!r}")
        try:
            value = yaml.safe_load(text) if text.strip() else None
        except yaml.YAMLError:
            raise ValueError(f"--set {key}: value {text!r} is not valid YAML") from None
        if kinds.get(key, "").startswith("int") and isinstance(value, (str, float)):
            value = _whole_number(value, key)
        out[key] = value
    check_options(out, "--set")
    return out


def _whole_number(value, key: str):
    try:
        number = float(value)
    except ValueError:
        return value  # check_options names the bad value
    return int(number) if number.is_integer() else value
