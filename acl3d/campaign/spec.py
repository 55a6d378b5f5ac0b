"""Campaign specs: a base training config and a grid of axes, expanded into named runs.

A spec is a YAML mapping::

    name: quick
    description: one line for `acl3d campaign list`
    base: {student: ppo, preset: fast, steps: 100000}   # TrainConfig options of every run
    grid:                      # axes, expanded in this order (a product)
      teacher: [random, alp-gmm]              # a list: values of one TrainConfig option
      criterion:                              # a mapping: named settings of several options
        mostly-unfeasible: {bounds: {stump_height: [0, 9]}}
        variety-of-students:                  # named settings may hold variants (one run each)
          variants: {spider-sac: {body: spider, student: sac}, ...}
    seeds: 16                  # or a list of seeds
    exclude: [{teacher: adr, expert_knowledge: "no"}]   # runs matching all keys are skipped
                               # (a list matches any of its values: {seed: [8, 9]})
    baseline: random           # the reference teacher of `acl3d analyze`

`--budget F` multiplies every step count of the spec (steps, and the schedules measured in
steps, so a forgetting student is still reset at 7/20 of the run); `--seeds N` replaces the
seeds by 0..N-1; `--set KEY=VALUE` sets a TrainConfig option of every run, unscaled.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from acl3d import validation as check
from acl3d.campaign.options import CAMPAIGN_OWNED, check_options
from acl3d.training import TrainConfig

# Step counts scaled by --budget (the run length and the schedules measured in steps).
STEP_COUNTS = (
    "steps",
    "reset_student_every",
    "eval_every",
    "checkpoint_every",
    "periodical_samples_every",
)
# Axes named first in run names, in this order; other axes follow in spec order.
NAME_ORDER = ("teacher", "env", "body", "student", "criterion", "expert_knowledge")
_SPEC_KEYS = {"name", "description", "base", "grid", "seeds", "exclude", "baseline", "only"}


@dataclass(frozen=True)
class RunSpec:
    """One run of a campaign: its directory name, its labels (axis -> value) and options."""

    name: str
    labels: dict[str, Any]
    options: dict[str, Any]


@dataclass
class CampaignSpec:
    name: str
    description: str = ""
    base: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, Any] = field(default_factory=dict)
    seeds: list[int] = field(default_factory=lambda: [0])
    exclude: list[dict[str, Any]] = field(default_factory=list)
    baseline: str = "random"
    # the cells selected (`--only`): axis -> the labels kept; the runs keep the names they
    # have in the whole campaign
    only: dict[str, list[str]] = field(default_factory=dict)

    # ------------------------------------------------------------------ building
    @classmethod
    def from_dict(cls, doc: dict, where: str = "spec") -> CampaignSpec:
        if not isinstance(doc, dict):
            raise ValueError(
                f"{where}: a campaign spec must be a mapping, got {type(doc).__name__}"
            )
        unknown = sorted(set(doc) - _SPEC_KEYS)
        if unknown:
            raise ValueError(f"{where}: unknown key(s) {unknown}; valid: {sorted(_SPEC_KEYS)}")
        if not isinstance(doc.get("name"), str) or not doc["name"]:
            raise ValueError(f"{where}: 'name' must be a non-empty string")
        spec = cls(
            name=doc["name"],
            description=str(doc.get("description", "")),
            base=dict(doc.get("base") or {}),
            grid=dict(doc.get("grid") or {}),
            seeds=_seed_list(doc.get("seeds", 1), f"{where}: seeds"),
            exclude=_rule_list(doc.get("exclude"), f"{where}: exclude"),
            baseline=str(doc.get("baseline", "random")),
            only={str(k): [str(v) for v in vs] for k, vs in (doc.get("only") or {}).items()},
        )
        spec.check(where)
        return spec

    def check(self, where: str = "spec") -> None:
        """Names and types of every option, before anything runs."""
        check_options(self.base, f"{where}: base")
        for axis, values in self.grid.items():
            for _, _, options in _axis_entries(axis, values, f"{where}: grid.{axis}"):
                check_options(options, f"{where}: grid.{axis}")
        for axis in self.only:
            if axis not in self.grid:
                raise ValueError(f"{where}: only.{axis} is not an axis of the grid")
        for i, rule in enumerate(_rule_list(self.exclude, f"{where}: exclude")):
            if not isinstance(rule, dict) or not rule:
                raise ValueError(f"{where}: exclude[{i}] must be a non-empty mapping, got {rule!r}")

    def scaled(
        self, budget: float = 1.0, seeds: int | None = None, sets: dict | None = None
    ) -> CampaignSpec:
        """The spec with step counts x `budget`, seeds 0..`seeds`-1 and `sets` applied."""
        if isinstance(budget, bool) or not isinstance(budget, (int, float)) or not budget > 0:
            raise ValueError(f"budget must be a number > 0, got {budget!r}")
        if not math.isfinite(budget):
            raise ValueError(f"budget must be finite, got {budget!r}")
        sets = dict(sets or {})
        check_options(sets, "--set")
        spec = dataclasses.replace(
            self,
            base=_scale(self.base, budget),
            grid={axis: _scale_axis(axis, values, budget) for axis, values in self.grid.items()},
            seeds=list(self.seeds) if seeds is None else _seed_list(seeds, "seeds"),
        )
        if sets:
            spec.base = {**spec.base, **sets}
            spec.grid = {a: _drop_keys(a, v, sets) for a, v in spec.grid.items()}
            spec.grid = {a: v for a, v in spec.grid.items() if v is not None}
        return spec

    # ------------------------------------------------------------------ expansion
    def expand(self) -> list[RunSpec]:
        """Every run of the grid x seeds, minus the excluded ones, with unique names."""
        axes = [
            (axis, _axis_entries(axis, values, f"grid.{axis}"))
            for axis, values in self.grid.items()
        ]
        named = [a for a in NAME_ORDER if a in self.grid] + [
            a for a in self.grid if a not in NAME_ORDER
        ]
        in_name = {a for a, entries in axes if len(entries) > 1 or isinstance(self.grid[a], dict)}
        runs = []
        for combo in itertools.product(*(entries for _, entries in axes)):
            labels: dict[str, Any] = {}
            parts: dict[str, str] = {}
            options = dict(self.base)
            for (axis, _), (label, variant, opts) in zip(axes, combo):
                labels[axis] = label
                parts[axis] = f"ek-{label}" if axis == "expert_knowledge" else _slug(label)
                if variant is not None:
                    labels["variant"] = variant
                    parts[axis] += "-" + _slug(variant)
                options.update(opts)
            for key in NAME_ORDER:  # the run's actual values, for analysis and exclusion
                if key not in labels and key in options:
                    labels[key] = options[key]
            if any(str(labels[a]) not in kept for a, kept in self.only.items()):
                continue
            for seed in self.seeds:
                run_labels = {**labels, "seed": seed}
                if any(_matches(rule, run_labels, options) for rule in self.exclude):
                    continue
                name = "__".join([*(parts[a] for a in named if a in in_name), f"s{seed}"])
                runs.append(RunSpec(name, run_labels, {**options, "seed": seed}))
        if not runs:
            raise ValueError(
                f"spec {self.name!r}: its exclude rules remove every run of the grid "
                f"({len(self.exclude)} rules: {self.exclude}); nothing to run"
            )
        names = [r.name for r in runs]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ValueError(f"spec {self.name!r}: run names collide: {duplicates[:5]}")
        return runs

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# ---------------------------------------------------------------------- option checks
def check_runs(runs: list[RunSpec], on_this_machine: bool = True) -> None:
    """Every run's options as `train` will check them (names, bounds, combinations), so that a
    bad value is refused before the campaign writes anything or starts any run; without the
    bounds relative to this machine (cores, devices) when the runs train on other machines."""
    from acl3d.training.config import validate
    from acl3d.training.student_settings import student_params

    for run in runs:
        check.path("run name", run.name)  # a grid label too long for a folder name
        try:
            config = TrainConfig.from_dict({**run.options, "out": run.name})
            validate(config, on_this_machine=on_this_machine)
            student_params(config)
        except ValueError as exc:
            raise ValueError(f"run {run.name}: {exc}") from None


def _rule_list(rules, where: str) -> list:
    if rules is None:
        return []
    if not isinstance(rules, list):
        raise ValueError(f"{where}: expected a list of mappings, got {rules!r}")
    return list(rules)


def _seed_list(seeds, where: str) -> list[int]:
    if isinstance(seeds, int) and not isinstance(seeds, bool):
        if seeds < 1:
            raise ValueError(f"{where}: the number of seeds must be >= 1, got {seeds}")
        return list(range(seeds))
    if (
        isinstance(seeds, list)
        and seeds
        and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)
    ):
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"{where}: seeds must be distinct, got {seeds}")
        return list(seeds)
    raise ValueError(f"{where}: expected a count >= 1 or a list of seeds >= 0, got {seeds!r}")


# ---------------------------------------------------------------------- axes
def _axis_entries(axis: str, values, where: str) -> list[tuple[str, str | None, dict]]:
    """(label, variant, options) of each value of an axis."""
    if isinstance(values, list):
        if not values:
            raise ValueError(f"{where}: an axis needs at least one value")
        if axis in CAMPAIGN_OWNED:
            raise ValueError(f"{where}: {axis!r} is set by the campaign (use seeds)")
        return [(value, None, {axis: value}) for value in values]
    if isinstance(values, dict) and values:
        entries = []
        for label, settings in values.items():
            settings = dict(settings or {})
            variants = settings.pop("variants", None)
            if variants is None:
                entries.append((str(label), None, settings))
                continue
            if not isinstance(variants, dict) or not variants:
                raise ValueError(f"{where}.{label}.variants must be a non-empty mapping")
            for vname, vopts in variants.items():
                entries.append((str(label), str(vname), {**settings, **dict(vopts or {})}))
        return entries
    raise ValueError(
        f"{where}: an axis is a list of values or a mapping of named settings, got {values!r}"
    )


def _scale(options: dict, budget: float) -> dict:
    """Positive step counts x `budget`, rounded, at least 1; other values are left for
    `check_runs` to accept (0 turns a schedule off) or refuse (a negative count)."""
    out = dict(options)
    for key in STEP_COUNTS:
        value = out.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0:
            scaled = value * budget
            if not math.isfinite(scaled):
                raise ValueError(
                    f"budget={budget!r}: {key}={value} x budget is not a finite number"
                )
            out[key] = max(1, int(round(scaled)))
    return out


def _scale_axis(axis: str, values, budget: float):
    if isinstance(values, list):
        return [_scale({axis: v}, budget)[axis] for v in values]
    scaled = {}
    for label, settings in values.items():
        settings = dict(settings or {})
        if isinstance(settings.get("variants"), dict):
            settings["variants"] = {
                k: _scale(dict(v or {}), budget) for k, v in settings["variants"].items()
            }
        scaled[label] = _scale(settings, budget)
    return scaled


def _drop_keys(axis: str, values, sets: dict):
    """A --set option wins over the grid: a list axis it sets disappears, named settings lose it."""
    if isinstance(values, list):
        return None if axis in sets else values
    out = {}
    for label, settings in values.items():
        settings = {k: v for k, v in dict(settings or {}).items() if k not in sets}
        if isinstance(settings.get("variants"), dict):
            settings["variants"] = {
                k: {kk: vv for kk, vv in dict(v or {}).items() if kk not in sets}
                for k, v in settings["variants"].items()
            }
        out[label] = settings
    return out


def _matches(rule: dict, labels: dict, options: dict) -> bool:
    """Whether a run matches every key of an exclude rule; a list in the rule matches any of its
    values (`{teacher: [riac, adr], seed: [8, 9]}`), a list-valued option only as a whole."""
    for key, wanted in rule.items():
        value = labels.get(key, options.get(key))
        if isinstance(wanted, list) and not isinstance(value, list):
            if value not in wanted:
                return False
        elif value != wanted:
            return False
    return True


def _slug(value) -> str:
    text = str(value)
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in text)


# ---------------------------------------------------------------------- loading
def builtin_names() -> list[str]:
    folder = resources.files("acl3d.campaign") / "specs"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def load_spec(name_or_path: str) -> CampaignSpec:
    """A built-in spec by name (`acl3d campaign list`) or a YAML file."""
    path = Path(name_or_path)
    if path.suffix.lower() in (".yaml", ".yml"):
        if not path.exists():
            raise ValueError(f"campaign spec file {name_or_path!r} does not exist")
        text, where = path.read_text(), str(path)
    elif name_or_path in builtin_names():
        text = (resources.files("acl3d.campaign") / "specs" / f"{name_or_path}.yaml").read_text()
        where = name_or_path
    else:
        raise ValueError(
            f"campaign spec {name_or_path!r}: not a built-in ({', '.join(builtin_names())}) "
            "nor a .yaml file"
        )
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"{where}: not valid YAML: {exc}") from None
    return CampaignSpec.from_dict(doc, where)
