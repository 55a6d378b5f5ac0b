"""`acl3d campaign list | show SPEC | run SPEC --out DIR | status DIR | export DIR --protocol P`:
benchmark campaigns."""

from __future__ import annotations

import argparse
import sys


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    sub.add_parser("list", help="list the built-in campaign specs")
    show = sub.add_parser("show", help="print a spec's runs (after --budget/--seeds/--set)")
    show.add_argument("spec", help="built-in spec name or a YAML file")
    _scaling_options(show)
    run = sub.add_parser("run", help="run a campaign (or continue it in the same --out)")
    run.add_argument("spec", help="built-in spec name or a YAML file")
    run.add_argument("--out", required=True, help="campaign directory")
    _scaling_options(run)
    run.add_argument(
        "--executor",
        choices=("ray", "local"),
        default="ray",
        help="ray (default: a local Ray instance, or --address) or local (spawned processes, "
        "no Ray needed)",
    )
    run.add_argument("--address", help="Ray cluster to join (default: a local Ray instance)")
    run.add_argument("--max-parallel", type=int, metavar="K", help="runs at the same time")
    run.add_argument(
        "--retries", type=int, default=2, help="extra attempts of a failed run (default 2)"
    )
    status = sub.add_parser("status", help="progress of a campaign directory")
    status.add_argument("dir", help="campaign directory")
    export = sub.add_parser(
        "export", help="write a campaign's finished runs as compact reference results"
    )
    export.add_argument("dir", help="campaign directory")
    export.add_argument("--protocol", required=True, help="protocol name, e.g. stump-v1")
    export.add_argument(
        "--out", help="destination (default: acl3d/results/PROTOCOL of this acl3d, replaced)"
    )
    export.add_argument(
        "--add",
        action="store_true",
        help="keep the runs already exported there that this campaign lacks (the same protocol "
        "and spec, other cells or seeds: a protocol grown across machines)",
    )


def _scaling_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--budget", type=float, default=1.0, help="multiply every step count by F")
    p.add_argument("--seeds", type=int, help="use seeds 0..N-1 instead of the spec's")
    p.add_argument(
        "--set",
        dest="sets",
        action="append",
        metavar="KEY=VALUE",
        help="training option for every run (repeatable), e.g. --set steps=4096",
    )
    p.add_argument(
        "--only",
        action="append",
        metavar="AXIS=LABEL",
        help="keep only the runs with this grid label or seed (repeatable: labels of one "
        "axis add up), e.g. --only teacher=alp-gmm --only seed=1 re-runs one cell",
    )


def _check_numbers(args) -> None:
    """The numbers typed, named as typed, before the executor or the spec is looked at: a
    negative --budget is named even where Ray is not installed."""
    from acl3d import validation as check

    check.real("--budget", args.budget, 0, exclusive_low=True)
    if args.seeds is not None:
        check.integer("--seeds", args.seeds, 1)
    if args.action == "run":
        check.integer("--retries", args.retries, 0)
        if args.max_parallel is not None:
            check.integer("--max-parallel", args.max_parallel, 1)


def _spec(args):
    from acl3d.campaign.options import parse_set
    from acl3d.campaign.spec import load_spec

    spec = load_spec(args.spec).scaled(args.budget, args.seeds, parse_set(args.sets))
    return narrowed(spec, args.only or [])


def narrowed(spec, rules: list[str]):
    """The spec restricted to the grid labels and seeds of `rules` ("AXIS=LABEL"; "seed=N"
    keeps seed N, whether or not the spec lists it): one cell of a campaign, or several, since
    the labels of one axis add up (`--only teacher=random --only teacher=alp-gmm`)."""
    import dataclasses

    grid, seeds = spec.grid, list(spec.seeds)
    wanted: dict[str, list[str]] = {}
    for rule in rules:
        axis, sep, label = rule.partition("=")
        if not sep or not axis or not label:
            raise ValueError(f"--only must be AXIS=LABEL, got {rule!r}")
        if axis == "seed":
            if not label.isdigit():
                raise ValueError(f"--only seed must be an integer >= 0, got {label!r}")
        elif axis not in grid:
            raise ValueError(f"--only {axis!r}: not an axis of {spec.name}; axes: "
                             f"{', '.join([*grid, 'seed'])}")  # fmt: skip
        else:
            values = grid[axis]
            labels = [str(v) for v in values] if not isinstance(values, dict) else list(values)
            if label not in labels:
                raise ValueError(f"--only {axis}={label!r}: not in {spec.name}; {axis} is one "
                                 f"of {', '.join(labels)}")  # fmt: skip
        wanted.setdefault(axis, []).append(label)
    only = {axis: labels for axis, labels in wanted.items() if axis != "seed"}
    if "seed" in wanted:
        seeds = sorted({int(label) for label in wanted["seed"]})
    return dataclasses.replace(spec, seeds=seeds, only={**spec.only, **only})


def run(args) -> int:
    actions = {"list": _list, "show": _show, "run": _run, "status": _status, "export": _export}
    return actions[args.action](args)


def _list(args) -> int:
    from acl3d.campaign.spec import builtin_names, load_spec

    for name in builtin_names():
        spec = load_spec(name)
        print(f"{name:12s} {len(spec.expand()):5d} runs  {spec.description}")
    return 0


def _show(args) -> int:
    import yaml

    from acl3d.campaign.spec import check_runs

    _check_numbers(args)
    spec = _spec(args)
    runs = spec.expand()
    check_runs(runs)
    print(yaml.safe_dump({"base": spec.base, "grid": spec.grid}, sort_keys=False).rstrip())
    print(f"# {len(runs)} runs, {sum(r.options.get('steps', 0) for r in runs):,} steps in all")
    for r in runs:
        extra = {k: v for k, v in r.options.items() if spec.base.get(k) != v}
        print(f"{r.name}  {extra}")
    return 0


def _run(args) -> int:
    from acl3d.campaign.executors import check_executor

    _check_numbers(args)
    check_executor(args.executor, args.max_parallel, args.address)  # then: names a missing extra
    from acl3d.campaign.runner import run_campaign

    spec = _spec(args)
    invocation = {
        "command": sys.argv,
        "budget": args.budget,
        "seeds": args.seeds,
        "set": args.sets or [],
        "only": args.only or [],
        "executor": args.executor,
    }
    try:
        result = run_campaign(
            spec,
            args.out,
            executor=args.executor,
            address=args.address,
            max_parallel=args.max_parallel,
            retries=args.retries,
            invocation=invocation,
        )
    except KeyboardInterrupt:
        print(f"acl3d campaign: interrupted; continue with the same command (--out {args.out})")
        return 130
    print(
        f"campaign {spec.name}: {len(result.finished)} runs finished, {len(result.failed)} failed"
        + (f" ({', '.join(result.failed)})" if result.failed else "")
    )
    return 1 if result.failed else 0


def _status(args) -> int:
    from rich.console import Console

    from acl3d.campaign.progress import read_states, status_table, summarize
    from acl3d.campaign.runner import CampaignDir
    from acl3d.campaign.spec import RunSpec

    camp = CampaignDir(args.dir)
    doc = camp.read()
    runs = [RunSpec(r["name"], r["labels"], r["options"]) for r in doc["runs"]]
    states = read_states(camp, runs)
    counts = summarize(states)
    title = f"campaign {doc['spec']['name']}: " + ", ".join(f"{v} {k}" for k, v in counts.items())
    Console().print(status_table(states, title=title))
    return 0


def _export(args) -> int:
    from pathlib import Path

    from acl3d import results
    from acl3d.analysis.export import earlier_export, export_campaign
    from acl3d.campaign.runner import CampaignDir, merged_spec, spec_differences
    from acl3d.campaign.spec import builtin_names, load_spec

    out = Path(args.out) if args.out else Path(results.__file__).parent / args.protocol
    camp = CampaignDir(args.dir)
    manifest = camp.read() if camp.manifest.exists() else {}
    ran = (manifest.get("spec") or {}).get("name")
    planned = None  # a built-in protocol's campaign plans its whole spec, however many cells ran
    if args.protocol in builtin_names() and ran == args.protocol:
        planned = [run.labels for run in load_spec(args.protocol).expand()]
    _check_export_out(args, out, manifest, shipped=not args.out)
    spec = None  # the manifest's
    if args.add:
        earlier, ours = (
            earlier_export(out, args.protocol).get("spec") or {},
            manifest.get("spec") or {},
        )
        spec = merged_spec(earlier, ours, grid_may_grow=True)
        if spec is None:
            differ = spec_differences(earlier, ours, grid_may_grow=True)
            raise ValueError(
                f"--add: the runs in {str(out)!r} were made under another spec than campaign "
                f"{args.dir!r} (its {', '.join(differ)} differ; a grid may only add labels); "
                "export to another --out"
            )
    names = export_campaign(args.dir, out, args.protocol, planned, add=args.add, spec=spec)
    print(f"{len(names)} finished runs exported to {out}")
    return 0


def _check_export_out(args, out, manifest: dict, shipped: bool) -> None:
    """An export replaces its folder as a whole: refused where that folder holds the campaign
    or files that are no export, and where it would replace acl3d's shipped results of a
    protocol with a campaign that is not that protocol at full budget."""
    from pathlib import Path

    source, target = Path(args.dir).resolve(), Path(out).resolve()
    if target == source or target in source.parents:
        raise ValueError(
            f"--out={str(out)!r} holds the campaign {args.dir!r}, and an export replaces its "
            "folder as a whole; choose another --out"
        )
    if target.is_dir() and any(target.iterdir()) and not (target / "protocol.yaml").exists():
        raise ValueError(
            f"--out={str(out)!r} holds files that are not an export (no protocol.yaml), and an "
            "export replaces its folder as a whole; choose a new folder or an earlier export"
        )
    name = (manifest.get("spec") or {}).get("name")
    budget = (manifest.get("invocation") or {}).get("budget", 1.0)
    if shipped and target.exists() and (name != args.protocol or budget != 1.0):
        raise ValueError(
            f"campaign {args.dir!r} ({name or 'no campaign.yaml'}, budget {budget}) is not "
            f"protocol {args.protocol!r} at full budget: exporting it without --out would "
            f"replace the {args.protocol} results shipped with acl3d ({out}); pass --out DIR"
        )
