"""Replay a finished torch-native run's teacher load on this machine: the teacher's share of a
run measured without the GPU the run trained on, and what rounds of teacher calls save.

A torch-native run hands its worlds' finished episodes to its curriculum at each step that ends
one (`CurriculumRounds.sync`), which learns them and draws the resetting worlds' next tasks, at
every such step or, with a reserve of tasks drawn ahead, in rounds. The run's `episodes.csv`
holds every episode with its step and task, so these syncs can be played again in order, through
a controller built from the run's own config, with the run's cadence between steps (the seconds
per step its `status.json` recorded for collecting and updating, slept here). For each
`--reserve` (default: the run's own rule, and 0), on a fresh controller: the teacher calls
(rounds), the teacher's wall seconds and the share of the run's wall time the replayed teacher
would take, against what the run recorded on its own host; then the CPU seconds of the whole
replay (this process: the teacher's computing; the rest of the wall time is waiting, for a GMM
refit not done in time or, on a loaded machine, for the CPU).

    python scripts/bench_teacher_load.py RUN [--reserve 0 --reserve 64] [--setup-seconds 8]
        [--no-cadence] [--profile]

`--setup-seconds`: the time between building the teacher and the first step (a run builds its
worlds after its teacher; a GMM teacher's refit workers start meanwhile). Run it alone on the
machine: the wait is noise on a loaded one.
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
from acl3d.training.config import TrainConfig, uses_many_worlds
from acl3d.training.run_dir import RunDir
from acl3d.training.session import build_controller, probe_env, probe_task_space
from acl3d.training.torch_student.curriculum_rounds import CurriculumRounds, reserve_for
from acl3d.training.torch_student.phase_times import PhaseTimes


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


def replay(sync: CurriculumRounds, batches, n_envs: int, gap: float) -> tuple[int, float]:
    """(teacher calls, CPU seconds of the replay) over the run's syncs, `gap` seconds apart (a
    sleep: no CPU; the CPU clock is read once around the whole replay, as it is slow to read)."""
    calls, draw = 0, sync.controller.sample_training_tasks

    def counted(n):
        nonlocal calls
        calls += 1
        return draw(n)

    sync.controller.sample_training_tasks = counted
    cpu = time.process_time()
    sync.sync(EpisodeBatch.empty(sync.controller.task_space.dim), np.arange(n_envs))
    for batch in batches:
        time.sleep(gap)
        sync.sync(batch, batch.env_ids)
    return calls, time.process_time() - cpu


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("run", type=Path, help="a finished run directory of the rsl-ppo student")
    p.add_argument("--reserve", type=int, action="append", help="tasks drawn ahead (repeat)")
    p.add_argument("--setup-seconds", type=float, default=8.0)
    p.add_argument("--no-cadence", action="store_true", help="calls back to back")
    p.add_argument("--profile", action="store_true", help="cProfile of the replay, by own time")
    args = p.parse_args()
    if any(r < 0 for r in args.reserve or []):
        p.error(f"--reserve: {args.reserve} (allowed: integers >= 0)")
    if args.setup_seconds < 0:
        p.error(f"--setup-seconds: {args.setup_seconds} is negative (allowed: >= 0)")

    run = RunDir(args.run)
    recorded_config = TrainConfig.from_dict(run.read_config())  # maybe on a GPU this host lacks
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

    recorded = phases["teacher"]
    others = sum(phases.values()) - recorded
    print(
        f"{run.path.name}: teacher {config.teacher}, {config.n_envs} worlds, {len(batches)} steps "
        f"ending episodes, {sum(len(b) for b in batches)} episodes, {gap * 1e3:.1f} ms a step"
    )
    print(
        f"  recorded on the run's host: teacher {recorded:.2f} s, "
        f"{100 * recorded / (others + recorded):.2f}% of {others + recorded:.1f} s"
    )
    own = reserve_for(config.n_envs, uses_many_worlds(recorded_config))
    for reserve in args.reserve or [own, 0]:
        times = PhaseTimes()
        controller = build_controller(config, task_space, profile)
        sync = CurriculumRounds(controller, times, reserve, config.n_envs)
        time.sleep(args.setup_seconds)
        profiler = cProfile.Profile() if args.profile else None
        if profiler:
            profiler.enable()
        calls, cpu = replay(sync, batches, config.n_envs, gap)
        if profiler:
            profiler.disable()
        wall = times.seconds["teacher"]
        print(
            f"  replayed here, reserve {reserve}{' (the run rule)' if reserve == own else ''}: "
            f"{calls} teacher calls, teacher {wall:.2f} s, {100 * wall / (others + wall):.2f}% "
            f"of the run's other phases + it ({wall / recorded:.2f}x the recorded); the "
            f"replay's CPU {cpu:.2f} s"
        )
        if profiler:
            pstats.Stats(profiler).sort_stats("tottime").print_stats(15)


if __name__ == "__main__":  # the refit workers start in processes that import this file
    main()
