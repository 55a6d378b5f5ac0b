"""Benchmark teachers on the toy environment's variants against teachDeepRL's numbers.

Variants (all built from `acl3d.toy.ToyEnv`, 10 cubes per relevant dimension):
  plain       the 2-D toy of teachDeepRL's demo;
  irrelevant  + 3 task dimensions the toy ignores (distractors);
  noise       rewards + N(0, 0.1) noise;
  shuffled    rugged difficulty: the teacher's space is cut into 4 intervals per dimension and
              shuffled before the toy sees it (TeachMyAgent's `DimensionsShuffler`);
  unfeasible  mostly unfeasible space: [0, 3]^2 of which only [0, 1]^2 can be learned
              (`--ratio`, `--nb-dims` change the sizes, e.g. `--nb-dims 3 --ratio 2`).
For each preset (teachDeepRL / TeachMyAgent-benchmark hyper-parameters), variant and teacher:
% mastered cubes at 5k/10k/20k episodes (mean +- std over seeds) and the teacher's CPU seconds per
1000 episodes (process time inside sample_task/updates only), next to the original teachDeepRL
code's results where they were measured. Teachers whose module cannot be imported are skipped.
Teachers that need more than returns get what `acl3d.toy.run_teacher` gives (success, one-step
episodes, a learner-value proxy); the toy's facts (thresholds, easy corner) come from its
curriculum profile and each teacher's own toy settings (`toy_teacher_params`). A teacher that both presets configure alike runs once.

`--reference` also runs the original algorithms (`scripts/reference_teachers.py`: ALP-GMM,
Covar-GMM, RIAC as published, teachDeepRL defaults) on the same variants and seeds, and reports
their final score and Welch's p-value for the difference: a comparison with the originals
measured in the same run, on any variant, size or number of seeds. With `--component-shapes` it
also compares the shapes of the fitted mixture components (ALP-GMM, Covar-GMM): the share of
line-shaped ones (smallest principal task-space std < 1% of the range, largest > 5%) and the
median smallest principal std, over every fit of every seed.

    python scripts/bench_teachers.py --teachers alp-gmm,covar-gmm,riac --preset teachdeeprl
    python scripts/bench_teachers.py --seeds 1 --episodes 5000 --variants unfeasible
    python scripts/bench_teachers.py --reference --seeds 12 --variants unfeasible \
        --teachers alp-gmm,covar-gmm,riac --preset teachdeeprl
    python scripts/bench_teachers.py --component-shapes --seeds 3 --variants plain \
        --teachers alp-gmm --preset teachdeeprl
    python scripts/bench_teachers.py --reference --seeds 22 --variants unfeasible \
        --teachers riac --preset teachdeeprl --harness unit-space

`--harness` plays the unfeasible toy the way another harness around the original code might
have (`HARNESSES`), to measure whether such a difference moves the scores.
"""

from __future__ import annotations

import argparse
import inspect
import math
import sys
import time
import warnings

import numpy as np
from reference_teachers import CPU_COMPARABLE, REFERENCES, make_reference
from scipy.stats import ttest_ind
from threadpoolctl import threadpool_limits

from acl3d.task_space import TaskSpace
from acl3d.teachers import TEACHERS, make, teacher_class
from acl3d.teachers.dimensions_shuffler import DimensionsShuffler
from acl3d.teachers.expert_knowledge import toy_teacher_params
from acl3d.teachers.presets import PRESETS, preset_params
from acl3d.toy import MASTERED, ToyEnv, run_teacher

VARIANTS = ("plain", "irrelevant", "noise", "shuffled", "unfeasible")
# The original teachDeepRL code (tDRL defaults) on the same problems, 20k episodes: the 2-D toy
# (5 seeds) and [0,3]^2 with [0,1]^2 learnable (3 seeds); teacher CPU seconds per 1000 episodes.
REF_SCORE_20K = {
    "plain": {"random": 4.6, "alp-gmm": 35.0, "riac": 47.0, "covar-gmm": 63.0},
    "unfeasible": {"alp-gmm": 20.0, "riac": 27.0, "covar-gmm": 54.0},
}
REF_CPU_PER_1000 = {"alp-gmm": 0.56, "covar-gmm": 0.41, "riac": 1.0}
# Ways a harness around the original toy could have played the unfeasible variant (which the
# original toy lacks: it exits on a task outside [0, 1]^n).
HARNESSES = {
    "acl3d": "tasks outside the learnable box return 0 and teach nothing (acl3d's toy)",
    "edge-cubes": "tasks outside the learnable box are played in the edge cube they clip to",
    "unit-space": "the teacher works in [0, 1]^n and the toy receives task x ratio",
    "score-ge75": "a cube counts as mastered at competence >= 75 (instead of > 75)",
}


class EdgeCubesToy(ToyEnv):
    """Every task is learnable: `cube_of` clips an out-of-range task into an edge cube."""

    def learnable(self, task) -> bool:
        return True


class ScoreGe75Toy(ToyEnv):
    """The score counts cubes at competence >= 75 (the unlock threshold) as mastered."""

    def score(self) -> float:
        return float(100.0 * (self.competence >= MASTERED).mean())


def make_env(
    variant: str, seed: int, nb_dims: int, ratio: float, harness: str = "acl3d"
) -> tuple[ToyEnv, object, TaskSpace]:
    """The toy for `variant`, the map from teacher tasks to toy tasks (None: identity) and the
    teacher's task space; `harness` (unfeasible variant only) picks one of `HARNESSES`."""
    if harness != "acl3d":
        if variant != "unfeasible":
            raise ValueError(f"harness {harness!r} applies to the unfeasible variant only")
        toy = {"edge-cubes": EdgeCubesToy, "score-ge75": ScoreGe75Toy}.get(harness, ToyEnv)
        env = toy(nb_dims=nb_dims, nb_cubes=10, seed=seed, space_ratio=ratio)
        if harness != "unit-space":
            return env, None, env.task_space()
        unit = TaskSpace.from_bounds({"position": [0.0, 1.0, nb_dims]})
        return env, lambda task: np.asarray(task, dtype=np.float64) * ratio, unit
    kwargs = {
        "plain": {},
        "irrelevant": {"nb_irrelevant_dims": 3},
        "noise": {"noise": 0.1},
        "shuffled": {},
        "unfeasible": {"space_ratio": ratio},
    }[variant]
    env = ToyEnv(nb_dims=nb_dims, nb_cubes=10, seed=seed, **kwargs)
    space = env.task_space()
    if variant != "shuffled":
        return env, None, space
    return env, DimensionsShuffler(space.low, space.high, cuttings=4, seed=seed).forward, space


def principal_stds(teacher, span: np.ndarray) -> np.ndarray | None:
    """(components, task dims) principal standard deviations, in fractions of each range, of
    every mixture the teacher fitted (None for teachers without mixtures)."""
    covs = getattr(teacher, "fitted_covariances", None)  # the originals (reference_teachers)
    if covs is None:
        covs = teacher.bk.get("covariances") if hasattr(teacher, "bk") else None
    if not covs:
        return None
    d = len(span)
    task = np.concatenate([np.asarray(c)[:, :d, :d] for c in covs]) / np.outer(span, span)
    return np.sqrt(np.clip(np.linalg.eigvalsh(task), 0.0, None))


def shape_cells(stds: np.ndarray) -> str:
    """Share of line-shaped components and median smallest principal std."""
    smallest, largest = stds.min(axis=1), stds.max(axis=1)
    line = 100.0 * np.mean((smallest < 0.01) & (largest > 0.05))
    return f"{line:.1f}% | {np.median(smallest):.3f} | {len(stds)}"


def bench_one(
    name: str,
    preset: str | None,
    variant: str,
    seed: int,
    episodes: int,
    checkpoints,
    nb_dims,
    ratio,
    harness="acl3d",
) -> tuple[list[float], float, np.ndarray | None]:
    """Scores at `checkpoints`, CPU per 1000 episodes and component shapes (`principal_stds`)
    of one run; `preset=None` runs the original algorithm (`reference_teachers`) instead of
    acl3d's teacher."""
    env, to_env, space = make_env(variant, seed, nb_dims, ratio, harness)
    if preset is None:
        teacher = make_reference(name, space, seed)
    else:
        params = preset_params(preset, name) | toy_teacher_params(
            name, env.curriculum_profile, env.task_space()
        )
        teacher = make(name, space, seed=seed, **params)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
    every = math.gcd(*checkpoints)
    result = run_teacher(teacher, env, episodes, score_every=every, to_env=to_env)
    by_episode = dict(zip(result.episodes, result.scores))
    shapes = principal_stds(teacher, (space.high - space.low)[:nb_dims])
    return [by_episode[c] for c in checkpoints], result.cpu_per_1000, shapes


def effective_params(name: str, preset: str) -> dict:
    """Class defaults overridden by the preset (presets omit what equals the defaults)."""
    sig = inspect.signature(teacher_class(name).__init__)
    params = {
        k: p.default for k, p in sig.parameters.items() if k not in ("self", "task_space", "seed")
    }
    return params | preset_params(preset, name)


def run_seeds(name: str, preset: str | None, variant: str, checkpoints, args) -> list[tuple]:
    """`bench_one` for every seed of the command line."""
    return [
        bench_one(
            name,
            preset,
            variant,
            seed,
            args.episodes,
            checkpoints,
            args.nb_dims,
            args.ratio,
            args.harness,
        )
        for seed in range(args.seeds)
    ]


def compare_with_original(finals: np.ndarray, cpu: float, original: tuple | None) -> str:
    """Table cells: the original's final score, acl3d minus original, Welch's p-value, the
    original's CPU per 1000 episodes and acl3d's CPU over it (both measured in this run)."""
    if original is None:
        return " – | – | – | – | – |"
    original, original_cpu = original
    diff = finals.mean() - original.mean()
    with warnings.catch_warnings():  # identical samples (e.g. all 0): p is nan, said as such
        warnings.simplefilter("ignore", RuntimeWarning)
        p = ttest_ind(finals, original, equal_var=False).pvalue if len(finals) > 1 else np.nan
    cpu_cells = f" {original_cpu:.3f} | {cpu / original_cpu:.2f} |" if original_cpu else " – | – |"
    return f" {original.mean():.1f} ± {original.std():.1f} | {diff:+.1f} | {p:.2f} |" + cpu_cells


def _names(text: str, valid, what: str, parser) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in valid]
    if unknown:
        parser.error(f"unknown {what}(s) {unknown}; valid: {', '.join(valid)}")
    return names


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=20000)
    parser.add_argument(
        "--teachers", default=",".join(TEACHERS), help="comma-separated teacher names"
    )
    parser.add_argument("--preset", default="all", choices=["all", *PRESETS])
    parser.add_argument("--variants", default=",".join(VARIANTS), help="comma-separated variants")
    parser.add_argument("--nb-dims", type=int, default=2, help="relevant task dimensions")
    parser.add_argument(
        "--ratio", type=float, default=3.0, help="unfeasible: task-space side / learnable side"
    )
    parser.add_argument(
        "--harness",
        default="acl3d",
        choices=list(HARNESSES),
        help="how the unfeasible toy is played: "
        + "; ".join(f"{k}: {v}" for k, v in HARNESSES.items()),
    )
    parser.add_argument(
        "--reference",
        action="store_true",
        help="also run the original algorithms on the same variants and seeds",
    )
    parser.add_argument(
        "--component-shapes",
        action="store_true",
        help="also compare the mixture teachers' component shapes with the originals'",
    )
    args = parser.parse_args(argv)
    names = _names(args.teachers, TEACHERS, "teacher", parser)
    variants = _names(args.variants, VARIANTS, "variant", parser)
    if args.harness != "acl3d" and variants != ["unfeasible"]:
        parser.error(f"--harness {args.harness} needs --variants unfeasible, got {args.variants}")
    available = []
    for n in names:
        try:
            toy = ToyEnv()
            space = toy.task_space()
            make(n, space, seed=0, **toy_teacher_params(n, toy.curriculum_profile, space))
            available.append(n)
        except (ImportError, ValueError) as exc:  # not written yet, or needs inputs the toy lacks
            print(f"skipping {n}: {exc}", file=sys.stderr)
    checkpoints = [c for c in (5000, 10000, 20000) if c <= args.episodes] or [args.episodes]
    if checkpoints[-1] != args.episodes:
        checkpoints.append(args.episodes)
    presets = list(PRESETS) if args.preset == "all" else [args.preset]
    standard = (
        args.nb_dims == 2
        and args.ratio == 3.0
        and args.episodes == 20000
        and args.harness == "acl3d"
    )

    head = " | ".join(f"{c // 1000}k" if c % 1000 == 0 else str(c) for c in checkpoints)
    ref_head = (
        f" original {head.split(' | ')[-1]} | diff | p (Welch) | original CPU | CPU ratio (same run) |"
        if args.reference
        else ""
    )
    rows = [
        f"| variant | teacher | preset | {head} | tDRL 20k | score ratio | CPU s/1000 ep | tDRL CPU | CPU ratio |{ref_head}",
        "|" + "---|" * (len(checkpoints) + 8 + 5 * args.reference),
    ]
    originals: dict[tuple, tuple] = {}  # (variant, teacher) -> (final scores per seed, CPU)
    done: dict[tuple, tuple] = {}  # a teacher the presets configure alike runs once
    shapes: list[str] = []  # --component-shapes rows
    with_originals = args.reference or args.component_shapes
    for variant in variants:
        for preset in presets:
            for name in available:
                key = (variant, name, repr(sorted(effective_params(name, preset).items())))
                if key not in done:
                    t0 = time.time()
                    runs = run_seeds(name, preset, variant, checkpoints, args)
                    scores = np.asarray([r[0] for r in runs])
                    cpu = float(np.mean([r[1] for r in runs]))
                    done[key] = (scores.mean(axis=0), scores.std(axis=0), cpu, scores[:, -1])
                    if args.component_shapes:
                        shapes.append(f"| {variant} | {name} | {preset} | {_shapes(runs)}")
                    print(
                        f"done {variant} {name} ({preset}) in {time.time() - t0:.0f} s",
                        file=sys.stderr,
                        flush=True,
                    )
                mean, std, cpu, finals = done[key]
                if with_originals and name in REFERENCES and (variant, name) not in originals:
                    runs = run_seeds(name, None, variant, checkpoints, args)
                    originals[variant, name] = (
                        np.asarray([r[0][-1] for r in runs]),
                        float(np.mean([r[1] for r in runs])) if name in CPU_COMPARABLE else None,
                    )
                    if args.component_shapes:
                        shapes.append(f"| {variant} | {name} | original | {_shapes(runs)}")
                    print(f"done {variant} {name} (original)", file=sys.stderr, flush=True)
                ref_s = REF_SCORE_20K.get(variant, {}).get(name) if standard else None
                ref_c = REF_CPU_PER_1000.get(name)
                cells = " | ".join(f"{m:.1f} ± {s:.1f}" for m, s in zip(mean, std))
                score_ratio = f"{mean[-1] / ref_s:.2f}" if ref_s else "–"
                cpu_ratio = f"{cpu / ref_c:.2f}" if ref_c else "–"
                row = f"| {variant} | {name} | {preset} | {cells} | {ref_s if ref_s is not None else '–'} | {score_ratio} | {cpu:.3f} | {ref_c if ref_c is not None else '–'} | {cpu_ratio} |"
                if args.reference:
                    row += compare_with_original(finals, cpu, originals.get((variant, name)))
                rows.append(row)
    print(
        f"\n{args.seeds} seeds, {args.episodes} episodes, {args.nb_dims} relevant dims, 10 cubes/dim,"
        f" unfeasible ratio {args.ratio:g}, harness {args.harness}; tDRL references: tDRL defaults, 20k episodes"
        " (plain: 5 seeds, unfeasible: 3 seeds)."
    )
    print("\n".join(rows))
    if shapes:
        print(
            "\nMixture components over every fit and seed: line-shaped = smallest principal"
            " task-space std < 0.01 of the range and largest > 0.05.\n"
            "| variant | teacher | preset | line-shaped | median smallest std | components |\n"
            "|---|---|---|---|---|---|"
        )
        print("\n".join(row for row in shapes if not row.endswith("– |")))
    return 0


def _shapes(runs) -> str:
    stds = [r[2] for r in runs if r[2] is not None]
    return shape_cells(np.concatenate(stds)) + " |" if stds else "– |"


if __name__ == "__main__":
    # one BLAS/OpenMP thread: teachers' small matrix products gain nothing from more, and
    # process time would count idle spinning threads (sklearn's fits in the originals)
    with threadpool_limits(1):
        sys.exit(main())
