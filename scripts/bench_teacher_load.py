"""Replay a finished torch-native run's teacher load on this machine: the teacher's share of a
run measured without the GPU the run trained on.

A many-world run calls its curriculum once a step: the controller learns the episodes that
ended and draws the next tasks of the worlds that reset (`TorchRun`'s `_Curriculum.sync`). The
run's `episodes.csv` holds every episode with its step and task, so its calls can be played again
in order, through a controller built from the run's own config, with the run's cadence between
calls (the seconds per step its `status.json` recorded for collecting and updating, slept here).
Printed: the teacher's wall seconds, its CPU seconds (process time of this process: what the
teacher computes), the rest (waiting, mostly for a GMM refit not done when its episode came, or
for the CPU on a loaded machine), and the share of the run's wall time the replayed teacher
would take against the share the run recorded (the ratio says how much faster or slower the
teacher is here than on the run's host).

    python scripts/bench_teacher_load.py RUN [--setup-seconds 8] [--no-cadence] [--profile]

`--setup-seconds`: the time between building the teacher and the first step (a run builds its
worlds after its teacher; a GMM teacher's refit workers start meanwhile). Run it alone on the
machine: the wait column is noise on a loaded one.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from pathlib import Path

import numpy as np

from acl3d.envs.episode_statistics import EpisodeBatch
from acl3d.run_format.status import read_status
from acl3d.run_format.tables import read_csv
from acl3d.training.config import TrainConfig
from acl3d.training.run_dir import RunDir
from acl3d.training.session import build_controller, probe_env, probe_task_space


def step_batches(run: RunDir, task_names: list[str]) -> list[EpisodeBatch]:
    """The run's episodes as the batches its steps handed the curriculum, oldest first."""
    cols = {k: np.asarray(v) for k, v in read_csv(run.episodes_csv, strict=True).items()}
    missing = [name for name in ("step", "worker", "return", *task_names) if name not in cols]
    if missing:
        raise SystemExit(f"{run.episodes_csv}: no column(s) {missing}; is it a torch-native run?")
    steps = cols["step"].astype(np.int64)
    cuts = np.flatnonzero(np.diff(steps)) + 1
    tasks = np.stack([cols[name] for name in task_names], axis=1).astype(np.float32)
    batches = []
    for ix in np.split(np.arange(len(steps)), cuts):
        batches.append(
            EpisodeBatch(
                env_ids=cols["worker"][ix].astype(np.int64),
                tasks=tasks[ix],
                returns=cols["return"][ix].astype(np.float64),
                lengths=cols["length"][ix].astype(np.int64),
                successes=cols["success"][ix].astype(bool),
                truncated=cols["truncated"][ix].astype(bool),
                total_steps=steps[ix],
            )
        )
    return batches


def replay(controller, batches, n_envs: int, gap: float) -> tuple[float, float]:
    """(wall, CPU) seconds inside the controller over the run's calls, `gap` seconds apart."""
    wall = cpu = 0.0
    for k, batch in enumerate([None, *batches]):
        if k and gap:
            time.sleep(gap)
        w, c = time.perf_counter(), time.process_time()
        if batch is None:  # the reset of every world before the first step
            controller.sample_training_tasks(n_envs)
        else:
            controller.record_episodes(batch)
            controller.sample_training_tasks(len(batch))
        wall += time.perf_counter() - w
        cpu += time.process_time() - c
    return wall, cpu


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("run", type=Path, help="a finished run directory of the rsl-ppo student")
    p.add_argument("--setup-seconds", type=float, default=8.0)
    p.add_argument("--no-cadence", action="store_true", help="calls back to back")
    p.add_argument("--profile", action="store_true", help="cProfile of the replay, by own time")
    args = p.parse_args()
    if args.setup_seconds < 0:
        p.error(f"--setup-seconds: {args.setup_seconds} is negative (allowed: >= 0)")

    run = RunDir(args.run)
    config = TrainConfig.from_dict({**run.read_config(), "device": "cpu"})
    status = read_status(run.path)
    phases = status.fields.get("seconds_by_phase") if status else None
    if not phases:
        raise SystemExit(f"{run.path}: status.json records no seconds_by_phase (not finished?)")
    env = probe_env(config)
    try:
        task_space, profile = probe_task_space(config, env)
    finally:
        env.close()
    batches = step_batches(run, task_space.flat_names())
    vector_steps = config.steps / config.n_envs
    gap = 0.0 if args.no_cadence else (phases["collect"] + phases["update"]) / vector_steps

    controller = build_controller(config, task_space, profile)
    time.sleep(args.setup_seconds)
    profiler = cProfile.Profile() if args.profile else None
    if profiler:
        profiler.enable()
    wall, cpu = replay(controller, batches, config.n_envs, gap)
    if profiler:
        profiler.disable()

    recorded = phases["teacher"]
    others = sum(phases.values()) - recorded
    episodes = sum(len(b) for b in batches)
    print(
        f"{run.path.name}: teacher {config.teacher}, {config.n_envs} worlds, {len(batches) + 1} "
        f"calls, {episodes} episodes, {gap * 1e3:.1f} ms between calls"
    )
    total = others + recorded
    print(
        f"recorded on the run's host: teacher {recorded:.2f} s, {100 * recorded / total:.2f}% of {total:.1f} s"
    )
    print(
        f"replayed here: teacher {wall:.2f} s (CPU {cpu:.2f} s, waiting {wall - cpu:.2f} s), "
        f"{100 * wall / (others + wall):.2f}% of the run's other phases + it; "
        f"{wall / recorded:.2f}x the recorded"
    )
    if profiler:
        pstats.Stats(profiler).sort_stats("tottime").print_stats(20)


if __name__ == "__main__":  # the refit workers start in processes that import this file
    main()
