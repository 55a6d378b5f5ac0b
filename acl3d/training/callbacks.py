"""The SB3 callbacks of a training run, one job each, combined with SB3's `CallbackList`.

* `EpisodeLogCallback`   finished training episodes -> episodes.csv and TensorBoard curriculum/*
* `StudentResetCallback` re-initialise the student every N steps (the forgetting-student criterion)
* `EvaluationCallback`   test-set evaluation -> evals.csv, evals_tasks.csv, TensorBoard eval/*
* `CheckpointCallback`   a complete, resumable checkpoint
* `ExclusionCallback`    marks exploratory episodes' transitions so the updates leave them out

Periodic work happens at rollout starts, i.e. right after a training update, where SB3's state
is complete and a checkpoint resumes bit for bit; evaluation and checkpoint also run once at the
end of training. In a `CallbackList` they run in the order of `run_callbacks()`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

from acl3d.run_format.tables import CsvLog
from acl3d.training import students
from acl3d.training.exclusion import ExcludingBuffer
from acl3d.training.session import Session

EVAL_COLUMNS = (
    "step", "episodes", "mastered_pct", "mean_return", "std_return", "mean_length", "n_tasks",
    "wall_time_s",
)  # fmt: skip


def next_multiple(step: int, every: int) -> int:
    return (step // every + 1) * every


class PeriodicCallback(BaseCallback):
    """Calls `fire(step)` at the first rollout start at or after each multiple of `every` steps
    (counted from `start_step`), and once more when training ends if `at_end`."""

    def __init__(self, every: int, start_step: int, at_end: bool):
        super().__init__()
        self.every, self.at_end = int(every), at_end
        self.next = next_multiple(start_step, self.every)
        self.last = -1

    def fire(self, step: int) -> None:
        raise NotImplementedError

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        if self.model.num_timesteps >= self.next:
            self._fire()

    def _on_training_end(self) -> None:
        if self.at_end and self.last != self.model.num_timesteps:
            self._fire()

    def _fire(self) -> None:
        step = int(self.model.num_timesteps)
        self.fire(step)
        self.last = step
        self.next = next_multiple(step, self.every)


class EpisodeLogCallback(BaseCallback):
    """Writes every finished training episode (step, worker, return, length, success, task) and
    the curriculum's TensorBoard scalars at each rollout end."""

    def __init__(self, session: Session):
        super().__init__()
        self.session = session
        self.task_names = session.task_names
        self.csv = CsvLog(
            session.run.episodes_csv,
            ["step", "worker", "return", "length", "success", "truncated", *self.task_names],
        )
        self.bk_seen: dict[str, int] = {}

    def _on_training_start(self) -> None:
        self.bk_seen = {key: len(values) for key, values in self._teacher_bk().items()}

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        self.flush()

    def flush(self) -> None:
        """Log the episodes finished since the last call."""
        curriculum = self.session.curriculum_env
        finished = curriculum.pop_finished()
        if finished is None:
            return
        self.csv.write_rows(
            [
                int(step),
                int(worker),
                f"{ret:.6g}",
                int(length),
                int(success),
                int(truncated),
                *(f"{v:.6g}" for v in task),
            ]
            for step, worker, ret, length, success, truncated, task in zip(
                finished.total_steps, finished.env_ids, finished.returns, finished.lengths,
                finished.successes, finished.truncated, finished.tasks,
            )
        )  # fmt: skip
        for name, value in zip(self.task_names, finished.tasks.mean(axis=0)):
            self.logger.record(f"curriculum/mean_task/{name}", float(value))
        self.logger.record("curriculum/episode_return", float(finished.returns.mean()))
        self.logger.record("curriculum/success_rate", float(finished.successes.mean()))
        self.logger.record("curriculum/episodes", curriculum.episodes_done)
        for key, value in self.teacher_scalars().items():
            self.logger.record(f"curriculum/teacher/{key}", value)

    def _teacher_bk(self) -> dict[str, list]:
        """The teacher's book-keeping series (every `Teacher` keeps them in `bk`)."""
        return self.session.controller.teacher.bk

    def teacher_scalars(self) -> dict[str, float]:
        """Mean of each scalar book-keeping series of the teacher (ALPs, losses, KL, ...) over
        the entries added since the last log, for TensorBoard."""
        out = {}
        for key, values in self._teacher_bk().items():
            start = self.bk_seen.get(key, 0)
            new = [v for v in values[start:] if _is_number(v)]
            self.bk_seen[key] = len(values)
            if new:
                out[key] = float(np.mean(new))
        return out


class StudentResetCallback(PeriodicCallback):
    """Fresh networks (and an empty replay buffer) every `every` steps: a forgetting student."""

    def __init__(self, every: int, start_step: int):
        super().__init__(every, start_step, at_end=False)

    def fire(self, step: int) -> None:
        students.reinitialise(self.model)
        self.logger.record("curriculum/student_resets", step // self.every)


class EvaluationCallback(PeriodicCallback):
    """Plays the test set with the run's evaluation seed; writes the summary and every episode,
    records them in the controller and prints one line when verbose."""

    def __init__(self, session: Session, every: int, start_step: int):
        super().__init__(every, start_step, at_end=True)
        self.session = session
        run = session.run
        self.evals = CsvLog(run.evals_csv, list(EVAL_COLUMNS))
        self.tasks = CsvLog(
            run.evals_tasks_csv,
            ["step", "task_index", "return", "length", "success", *session.task_names],
        )

    def fire(self, step: int) -> None:
        s = self.session
        if s.config.verbose:  # a pass can take minutes; the progress bar stands still meanwhile
            print(
                f"[acl3d] step {step}: evaluating on {s.controller.nb_test_episodes} test tasks "
                f"({s.config.effective_eval_envs} envs)...",
                flush=True,
            )
        result = s.run_eval()
        summary = result.summary()
        self.evals.write(
            [
                step,
                s.curriculum_env.episodes_done,
                f"{summary['mastered_pct']:.4g}",
                f"{summary['mean_return']:.6g}",
                f"{summary['std_return']:.6g}",
                f"{summary['mean_length']:.6g}",
                summary["n_tasks"],
                f"{s.wall_time():.1f}",
            ]
        )
        rows = []
        for i, (task, ret, length, success) in enumerate(
            zip(result.tasks, result.returns, result.lengths, result.successes)
        ):
            s.controller.record_test_episode(task, ret, length, bool(success))
            rows.append(
                [step, i, f"{ret:.6g}", int(length), int(success), *(f"{v:.6g}" for v in task)]
            )
        self.tasks.write_rows(rows)
        self.logger.record("eval/mastered_pct", summary["mastered_pct"])
        self.logger.record("eval/mean_return", summary["mean_return"])
        self.logger.record("curriculum/mastered_pct", summary["mastered_pct"])
        self.logger.dump(step)
        if s.config.verbose:
            print(
                f"[acl3d] step {step}: {summary['mastered_pct']:.1f}% mastered, "
                f"mean return {summary['mean_return']:.1f}",
                flush=True,
            )


class CheckpointCallback(PeriodicCallback):
    """A complete checkpoint every `every` steps and at the end; `before_save` runs first (the
    episode log, so that the CSVs hold everything the checkpoint has seen)."""

    def __init__(self, session: Session, every: int, start_step: int, before_save: Callable):
        super().__init__(every, start_step, at_end=True)
        self.session, self.before_save = session, before_save

    def fire(self, step: int) -> None:
        self.before_save()
        self.session.save_checkpoint()


class ExclusionCallback(BaseCallback):
    """Robust PLR / ACCEL: at every step, marks in the student's rollout or replay buffer the
    transitions that belong to exploratory episodes (before SB3 adds them); logs the excluded
    share of PPO's rollout / SAC's replay buffer (`curriculum/excluded_fraction`)."""

    def __init__(self, session: Session):
        super().__init__()
        self.session = session

    def _buffer(self) -> ExcludingBuffer:
        model = self.model
        return model.rollout_buffer if isinstance(model, OnPolicyAlgorithm) else model.replay_buffer

    def _on_step(self) -> bool:
        self._buffer().exclude_next(self.session.curriculum_env.step_exploratory)
        return True

    def _on_rollout_end(self) -> None:
        self.logger.record("curriculum/excluded_fraction", self._buffer().excluded_fraction)


def run_callbacks(session: Session, start_step: int) -> list[BaseCallback]:
    """The run's callbacks in the order they must run: exclusions, reset, evaluate, log,
    checkpoint."""
    c = session.config
    episodes = EpisodeLogCallback(session)
    out: list[BaseCallback] = [ExclusionCallback(session)] if session.exclude_exploratory else []
    if c.reset_student_every:
        out.append(StudentResetCallback(c.reset_student_every, start_step))
    out += [
        EvaluationCallback(session, c.effective_eval_every, start_step),
        episodes,
        CheckpointCallback(session, c.effective_checkpoint_every, start_step, episodes.flush),
    ]
    return out


def _is_number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
