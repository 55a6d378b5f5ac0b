"""Running a campaign: the campaign directory, its lock, and the submit / retry loop.

    DIR/campaign.yaml     the (scaled) spec, the options it was run with, every run's labels and
                          training options: what `acl3d analyze` and `campaign status` read
    DIR/runs/NAME/        one ordinary run directory per run (+ campaign.log, failures/)
    DIR/.lock             locked (flock) by the campaign process using the directory

Running the same campaign again into the same directory continues it: finished runs are
skipped, runs with a checkpoint resume from it, the rest start afresh. A campaign may grow
(more seeds: its runs a superset of the directory's) or run a selection of its cells (`--only`,
the other started runs staying in the manifest), never change a started run. Each run gets
`1 + retries` attempts per invocation.
"""

from __future__ import annotations

import json
import os
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import yaml

from acl3d.campaign.executors import Job, check_executor, make_executor
from acl3d.campaign.lock import exclusive
from acl3d.campaign.progress import ProgressView
from acl3d.campaign.run_state import read_state, record_failure
from acl3d.campaign.spec import CampaignSpec, RunSpec, check_runs
from acl3d.training.sigterm import sigterm_interrupts

MANIFEST = "campaign.yaml"


@dataclass
class CampaignResult:
    finished: list[str]
    failed: list[str]


class CampaignDir:
    def __init__(self, path):
        self.path = Path(path).resolve()

    @property
    def manifest(self) -> Path:
        return self.path / MANIFEST

    def run_dir(self, name: str) -> Path:
        return self.path / "runs" / name

    def read(self) -> dict:
        if not self.manifest.exists():
            raise ValueError(f"{str(self.path)!r} is not a campaign directory (no {MANIFEST})")
        return yaml.safe_load(self.manifest.read_text())

    def prepare(self, spec: CampaignSpec, runs: list[RunSpec], invocation: dict) -> None:
        """Write the manifest, or check that the directory holds this campaign or one it may
        become: more runs, other options for runs that never started (a corrected command after
        a start whose runs were all refused), or a selection of its cells (`--only`): the started
        runs it leaves out stay in the manifest, its spec covering the labels and seeds of both."""
        doc = {
            "spec": spec.to_dict(),
            "invocation": invocation,
            "runs": [{"name": r.name, "labels": r.labels, "options": r.options} for r in runs],
        }
        if self.manifest.exists():
            old = self.read()
            new = {r["name"]: r for r in doc["runs"]}
            started = [r for r in old["runs"] if (self.run_dir(r["name"]) / "config.yaml").exists()]
            kept = [r for r in started if r["name"] not in new]
            changed = sorted(
                {name for name, _ in _comparable(started) - _comparable(doc["runs"]) if name in new}
            )
            merged = merged_spec(old["spec"], doc["spec"]) if kept else doc["spec"]
            if changed or merged is None:
                names = changed or [r["name"] for r in kept]
                raise ValueError(
                    f"{str(self.path)!r} holds campaign {old['spec']['name']!r} whose started "
                    f"runs {names[:3]}{' ...' if len(names) > 3 else ''} are not in this one "
                    "or have other options; continue it with the same spec and options (more "
                    "--seeds may be added, --only may select some of its cells), or choose "
                    "another --out"
                )
            if kept:  # in the order of the campaign both make up
                order = [r.name for r in CampaignSpec.from_dict(merged).expand()]
                outside = [r["name"] for r in kept if r["name"] not in order]
                if outside:  # a spec that excludes started runs is another campaign
                    raise ValueError(
                        f"{str(self.path)!r} holds started runs {outside[:3]} that this spec "
                        "excludes; continue it with a spec that keeps them, or choose another --out"
                    )
                doc["spec"] = merged
                doc["runs"] = sorted(
                    [*kept, *doc["runs"]],
                    key=lambda r: order.index(r["name"]) if r["name"] in order else len(order),
                )
            if _comparable(old["runs"]) == _comparable(doc["runs"]) and old["spec"] == merged:
                return
        self.path.mkdir(parents=True, exist_ok=True)
        tmp = self.manifest.with_name(MANIFEST + ".tmp")
        tmp.write_text(yaml.safe_dump(doc, sort_keys=False))
        os.replace(tmp, self.manifest)

    @contextmanager
    def lock(self):
        """Hold the directory for this campaign process (one holder; released when it exits,
        however it exits). Creates the directory."""
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # at or under a file, read-only, ...
            raise ValueError(f"out={str(self.path)!r} cannot be created: {exc.strerror}") from None
        with exclusive(self.path / ".lock", f"campaign directory {str(self.path)!r}"):
            yield


# The options only an environment can check, and what it checks them with.
_ENVIRONMENT_OPTIONS = ("env", "body", "env_kwargs", "bounds", "test_set", "nb_test_episodes")


def check_environments(runs: list[RunSpec]) -> None:
    """What only the environment can check (its `env_kwargs`, buildable `bounds`, the test set
    and its tasks), once per distinct environment setting: a bad value is refused here, before
    the campaign writes anything, instead of failing every attempt of its runs."""
    from acl3d.teachers import test_sets
    from acl3d.training import TrainConfig
    from acl3d.training.session import check_test_tasks, probe_env, probe_task_space

    seen = set()
    for run in runs:
        config = TrainConfig.from_dict({**run.options, "out": run.name})
        setting = json.dumps([getattr(config, k) for k in _ENVIRONMENT_OPTIONS], sort_keys=True)
        if setting in seen:
            continue
        seen.add(setting)
        try:
            env = probe_env(config)
            try:
                space, profile = probe_task_space(config, env)
                tasks = test_sets.resolve(config.test_set, space, config.nb_test_episodes, profile)
                check_test_tasks(env, tasks, space.flat_names())
            finally:
                env.close()
        except ValueError as exc:
            raise ValueError(f"run {run.name}: {exc}") from None


def merged_spec(old: dict, new: dict, grid_may_grow: bool = False) -> dict | None:
    """The spec of both invocations when they select cells of one campaign (the same name,
    base and grid): the cells and seeds of either, under the new spec's exclusions (a campaign
    may grow by cells it used to exclude; `prepare` refuses one that would exclude started
    runs); None when they are two campaigns. With `grid_may_grow` (an export's runs joined by
    a later campaign) the new grid may add labels to the old one's axes, every old cell kept as
    it was, and the merged spec takes the new grid."""
    if spec_differences(old, new, grid_may_grow):
        return None
    a, b = old.get("only") or {}, new.get("only") or {}
    only = {axis: a[axis] + [x for x in b[axis] if x not in a[axis]] for axis in a if axis in b}
    return {**new, "only": only, "seeds": sorted({*old["seeds"], *new["seeds"]})}


def spec_differences(old: dict, new: dict, grid_may_grow: bool = False) -> list[str]:
    """What makes `new` another campaign than `old`: "name", "base" (compared with the student
    parameters added since either was written pinned at their earlier values, so a spec that
    pins one of them at that value stays the same campaign) and "grid" (unless `grid_may_grow`
    and the new grid only adds labels to the old one's axes)."""
    differ = [key for key in ("name",) if old.get(key) != new.get(key)]
    differ += [] if _settled_base(old) == _settled_base(new) else ["base"]
    grid_ok = grid_holds(new, old) if grid_may_grow else old.get("grid") == new.get("grid")
    return differ + ([] if grid_ok else ["grid"])


def _settled_base(spec: dict) -> dict | None:
    base = spec.get("base")
    if not isinstance(base, dict) or not isinstance(base.get("student_params"), dict):
        return base
    from acl3d.training import TrainConfig
    from acl3d.training.students import added_parameters

    added = added_parameters(base.get("student", TrainConfig.student))
    return {**base, "student_params": {**added, **base["student_params"]}}


def grid_holds(spec: dict, other: dict) -> bool:
    """Whether `spec`'s grid has `other`'s axes and every label of them with the same options."""
    grid, theirs = spec.get("grid") or {}, other.get("grid") or {}
    return set(grid) == set(theirs) and all(
        grid[axis].get(label) == cell for axis in theirs for label, cell in theirs[axis].items()
    )


def _comparable(runs: list[dict]) -> set:
    return {(r["name"], json.dumps(r["options"], sort_keys=True)) for r in runs}


def cpus_of(options: dict) -> int:
    """CPUs a run declares: its torch threads (1 unless the spec or --set says otherwise)."""
    return int(options.get("torch_threads") or 1)


def run_campaign(
    spec: CampaignSpec,
    out,
    executor: str = "ray",
    address: str | None = None,
    max_parallel: int | None = None,
    retries: int = 2,
    invocation: dict | None = None,
    live: bool | None = None,
) -> CampaignResult:
    """Run (or continue) every run of `spec` under `out`; returns the finished and failed names."""
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ValueError(f"retries must be an integer >= 0, got {retries!r}")
    check_executor(executor, max_parallel, address)
    runs = spec.expand()
    unsized = [r.name for r in runs if "steps" not in r.options]
    if unsized:  # a campaign tells its finished runs by their steps
        raise ValueError(f"spec {spec.name!r}: runs {unsized[:3]} set no steps (base.steps)")
    check_runs(runs, on_this_machine=address is None)  # a cluster's nodes check their own bounds
    check_environments(runs)
    cpus = {cpus_of(r.options) for r in runs}
    if len(cpus) != 1:
        raise ValueError(f"every run of a campaign must use the same torch_threads, got {cpus}")
    camp = CampaignDir(out)
    with camp.lock():  # before the manifest: a refused second driver changes nothing
        camp.prepare(spec, runs, invocation or {})
        seeds = list(dict.fromkeys(r.options["seed"] for r in runs))
        todo = deque(  # seed by seed, so that a campaign cut short has every condition
            sorted(
                (
                    r
                    for r in runs
                    if not read_state(camp.run_dir(r.name), r.options["steps"]).finished
                ),
                key=lambda r: seeds.index(r.options["seed"]),
            )
        )
        pool = make_executor(executor, max_parallel, cpus.pop(), address)
        view = ProgressView(camp, runs, live=live)
        try:
            with sigterm_interrupts():  # `kill PID` stops it like Ctrl-C; after ray.init's own
                failed = _drive(pool, view, camp, runs, todo, retries)
        except BaseException:
            pool.shutdown(interrupt=True)
            view.close()
            raise
        pool.shutdown(interrupt=False)
        view.close()
    finished = [
        r.name for r in runs if read_state(camp.run_dir(r.name), r.options["steps"]).finished
    ]
    return CampaignResult(finished=finished, failed=failed)


def _drive(pool, view, camp: CampaignDir, runs: list[RunSpec], todo: deque, retries: int):
    """Keep the executor full, retry failed attempts, refresh the view; returns failed runs."""
    by_name = {r.name: r for r in runs}
    attempts: dict[str, int] = {}
    failed: list[str] = []
    while todo or pool.free_slots() < pool.capacity:
        while todo and pool.free_slots() > 0:
            run = todo.popleft()
            attempts[run.name] = attempts.get(run.name, 0) + 1
            run_dir = str(camp.run_dir(run.name))
            pool.submit(Job(run.name, run_dir, run.options, cpus_of(run.options)))
        for job, outcome in pool.wait(timeout=1.0):
            if outcome.ok:
                continue
            if outcome.traceback:
                record_failure(Path(job.run_dir), outcome.traceback)
            if outcome.retry and attempts[job.name] <= retries:
                todo.append(by_name[job.name])
            else:
                failed.append(job.name)
            view.note(f"{job.name}: attempt {attempts[job.name]} failed: {outcome.error}")
        view.refresh()
    return failed
