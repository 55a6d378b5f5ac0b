"""`train(config)`: a Stable-Baselines3 student learning on a teacher's curriculum, resumable.

The run is checked completely (names, bounds, teacher/profile combination, student settings)
before any worker starts, so a bad combination fails in a second with the reason. Periodic work
(student resets, evaluations, checkpoints) happens at rollout starts, i.e. right after a
training update, which is the point where SB3's state is complete and a resume is exact up to
the environment episodes that were in flight.
"""

from __future__ import annotations

import dataclasses
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

from acl3d.teachers.base import load_state, save_state
from acl3d.training import checkpoint as ckpt
from acl3d.training import students
from acl3d.training.curriculum import CurriculumVecEnv
from acl3d.training.evaluation import EvalResult, evaluate, make_predict
from acl3d.training.run_dir import CsvLog, RunDir, truncate_csv
from acl3d.training.workers import check_vec_env, make_env, make_vec_env

EXPERT_KNOWLEDGE: tuple[str, ...] = ("no", "low", "high")
TEACHMYAGENT_EVAL_EVERY = 500_000
MIN_DEFAULT_EVAL_EVERY = 50_000
# Evaluation envs get their own seed, the same at every evaluation, so successive evaluations
# differ only by the policy (not by the stump-height noise of the test tracks).
EVAL_SEED_OFFSET = 7919
TEACHMYAGENT_PERIODICAL_SAMPLES = 250_000


@dataclass
class TrainConfig:
    """Every option of a training run (the CLI, config files and `train()` share it)."""

    env: str = "stump-tracks"
    body: str = "classic_bipedal"
    teacher: str = "random"
    student: str = "sac"
    preset: str = "benchmark"
    steps: int = 2_000_000
    n_envs: int = 1
    seed: int = 0
    out: str | None = None
    expert_knowledge: str = "low"
    shuffle_dimensions: bool = False
    scale_reward: bool = False
    reset_student_every: int = 0
    bounds: dict[str, list[float]] = field(default_factory=dict)
    teacher_params: dict[str, Any] = field(default_factory=dict)
    student_params: dict[str, Any] = field(default_factory=dict)
    buffer_size: int | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    eval_every: int | None = None
    eval_envs: int | None = None
    eval_stochastic: bool = False
    test_set: str | None = None
    nb_test_episodes: int = 100
    checkpoint_every: int | None = None
    periodical_samples_every: int | None = None
    save_replay_buffer: bool = True
    vec_env: str = "auto"
    start_method: str = "forkserver"
    torch_threads: int = 1
    progress_bar: bool = True
    device: str = "cpu"
    verbose: int = 1

    # ------------------------------------------------------------------ derived values
    @property
    def effective_eval_every(self) -> int:
        """TeachMyAgent's 500k, scaled down to 5 evaluations for runs shorter than 2.5M steps.

        Never below 50k by default: one pass over the 100-task test set can cost up to 200k env
        steps, so runs shorter than 50k steps get only the final evaluation.
        """
        if self.eval_every is not None:
            return int(self.eval_every)
        return int(min(TEACHMYAGENT_EVAL_EVERY, max(MIN_DEFAULT_EVAL_EVERY, self.steps // 5)))

    @property
    def effective_checkpoint_every(self) -> int:
        return int(self.checkpoint_every or self.effective_eval_every)

    @property
    def effective_periodical_samples(self) -> int:
        if self.periodical_samples_every is not None:
            return int(self.periodical_samples_every)
        return int(min(TEACHMYAGENT_PERIODICAL_SAMPLES, max(1, self.steps // 10)))

    def __post_init__(self):
        for name in _COUNTS:  # accept 2e6 for 2000000 from Python callers
            value = getattr(self, name)
            if isinstance(value, float) and value.is_integer():
                setattr(self, name, int(value))

    @classmethod
    def from_dict(cls, values: dict) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown config option(s) {unknown}; valid: {sorted(known)}")
        return cls(**values)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class TrainResult:
    run_dir: Path
    steps: int
    final_eval: dict[str, float] | None


# ---------------------------------------------------------------------- validation
_COUNTS = (
    "steps", "n_envs", "nb_test_episodes", "torch_threads", "eval_envs", "eval_every",
    "checkpoint_every", "buffer_size", "reset_student_every", "periodical_samples_every", "seed",
)  # fmt: skip
_MAY_BE_ZERO = ("reset_student_every", "periodical_samples_every", "seed")


def _check_count(name: str, value) -> None:
    if value is None and name not in ("steps", "n_envs", "nb_test_episodes", "torch_threads"):
        return
    bound = 0 if name in _MAY_BE_ZERO else 1
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < bound:
        raise ValueError(f"{name} must be an integer >= {bound}, got {value!r}")


def validate(config: TrainConfig) -> None:
    """Cheap checks of names and numbers (everything that needs no environment)."""
    from acl3d.teachers import TEACHERS

    if config.teacher not in TEACHERS:
        raise ValueError(
            f"unknown teacher {config.teacher!r}; valid teachers: {', '.join(TEACHERS)}"
        )
    students.check_student(config.student, config.preset)
    if config.expert_knowledge not in EXPERT_KNOWLEDGE:
        raise ValueError(
            f"expert_knowledge {config.expert_knowledge!r} unknown; valid: {', '.join(EXPERT_KNOWLEDGE)}"
        )
    check_vec_env(config.vec_env, config.start_method)
    for name in _COUNTS:
        _check_count(name, getattr(config, name))
    if config.reset_student_every and config.reset_student_every >= config.steps:
        raise ValueError(
            f"reset_student_every ({config.reset_student_every}) must be < steps ({config.steps}), "
            "otherwise the student is never reset"
        )


def _student_params(config: TrainConfig) -> dict:
    overrides = dict(config.student_params)
    if config.buffer_size is not None:
        if config.student != "sac":
            raise ValueError(
                "buffer_size applies to the sac student only (ppo has no replay buffer)"
            )
        overrides["buffer_size"] = config.buffer_size
    return students.hyperparameters(config.student, config.preset, config.n_envs, overrides)


def _build_controller(config: TrainConfig, task_space):
    from acl3d.teachers.controller import TeacherController

    params = dict(config.teacher_params)
    if config.teacher == "lessons":  # ML-Agents' "progress" measure is relative to the budget
        params.setdefault("max_steps", int(config.steps))
    return TeacherController(
        config.teacher,
        task_space,
        config.seed,
        teacher_params=params or None,
        expert_knowledge=config.expert_knowledge,
        env_name=config.env,
        scale_reward=config.scale_reward,
        shuffle_dimensions=config.shuffle_dimensions,
        test_set=config.test_set,
        nb_test_episodes=config.nb_test_episodes,
        keep_periodical_task_samples=config.effective_periodical_samples,
    )


def _probe_task_space(config: TrainConfig):
    env = make_env(config.env, config.body, config.env_kwargs)
    try:
        task_space = getattr(env.unwrapped, "task_space", None)
        if task_space is None:
            raise ValueError(
                f"environment {config.env!r} has no task_space: no curriculum possible"
            )
        return task_space
    finally:
        env.close()


# ---------------------------------------------------------------------- the run
class _Session:
    """Builds the envs, student and controller of one (new or resumed) run and runs it."""

    def __init__(self, config: TrainConfig, run: RunDir, resume_from: Path | None):
        self.config, self.run, self.resume_from = config, run, resume_from
        task_space = _probe_task_space(config)
        if config.bounds:
            task_space = task_space.with_bounds(**{k: tuple(v) for k, v in config.bounds.items()})
        self.task_names = task_space.flat_names()
        self.controller = _build_controller(config, task_space)
        self.params = _student_params(config)
        self.train_env = None
        self.eval_env = None
        self.started = time.perf_counter()
        self.previous_wall_time = 0.0

    def __enter__(self):
        c = self.config
        self.curriculum_env = CurriculumVecEnv(
            make_vec_env(c.env, c.body, c.n_envs, c.env_kwargs, c.vec_env, c.start_method),
            self.controller,
        )
        env = self.curriculum_env
        self.vecnorm = None
        if students.uses_vecnormalize(c.student):
            env = self.vecnorm = VecNormalize(
                env,
                norm_obs=True,
                norm_reward=True,
                clip_obs=10.0,
                clip_reward=10.0,
                gamma=self.params.get("gamma", 0.99),
            )
        self.train_env = env
        self.eval_env = make_vec_env(
            c.env, c.body, c.eval_envs or c.n_envs, c.env_kwargs, c.vec_env, c.start_method
        )
        return self

    def __exit__(self, *exc):
        for env in (self.train_env, self.eval_env):
            if env is not None:
                try:
                    env.close()
                except (OSError, EOFError):  # a dead worker must not hide the real error
                    pass

    def normalize_obs(self):
        vn = self.vecnorm
        return None if vn is None else (lambda obs: vn.normalize_obs(np.asarray(obs, np.float32)))

    def build_student(self):
        c = self.config
        if self.resume_from is None:
            self.model = students.build(
                c.student, self.params, self.train_env, c.seed, str(self.run.tb), c.device
            )
            return
        folder = self.resume_from
        self.model = students.load(
            c.student, folder / "model.zip", env=self.train_env, device=c.device
        )
        self.model.tensorboard_log = str(self.run.tb)
        if self.vecnorm is not None:
            ckpt.load_normalization_into(self.vecnorm, folder / "model.zip")
        if (folder / "replay_buffer.npz").exists():
            ckpt.load_replay_buffer(self.model.replay_buffer, folder / "replay_buffer.npz")
        self.controller.load_state_dict(load_state(folder / "controller"))
        progress = load_state(folder / "progress")
        self.curriculum_env.total_steps = int(progress["num_timesteps"])
        self.curriculum_env.episodes_done = int(progress["episodes_done"])
        self.previous_wall_time = float(progress.get("wall_time_s", 0.0))
        self.train_env.seed(c.seed + int(progress["num_timesteps"]))
        ckpt.set_rng_state(load_state(folder / "rng"))

    def wall_time(self) -> float:
        """Seconds of training so far, over all sessions of the run."""
        return self.previous_wall_time + time.perf_counter() - self.started

    def save_checkpoint(self) -> Path:
        model, run = self.model, self.run
        folder = run.new_checkpoint_dir(model.num_timesteps)
        model.save(folder / "model.zip")
        if self.vecnorm is not None:
            ckpt.save_normalization(self.vecnorm, folder / "model.zip")
        if hasattr(model, "replay_buffer") and self.config.save_replay_buffer:
            ckpt.save_replay_buffer(model.replay_buffer, folder / "replay_buffer.npz")
        save_state(folder / "controller", self.controller.state_dict())
        save_state(folder / "rng", ckpt.rng_state())
        self.controller.dump(str(run.teacher_prefix))
        progress = {
            "num_timesteps": int(model.num_timesteps),
            "episodes_done": int(self.curriculum_env.episodes_done),
            "time": time.time(),
            "wall_time_s": self.wall_time(),
        }
        save_state(folder / "progress", progress)  # written last: marks the folder complete
        run.publish_checkpoint(folder)
        return folder

    def run_eval(self, seed: int) -> EvalResult:
        predict = make_predict(self.model, not self.config.eval_stochastic, self.normalize_obs())
        return evaluate(predict, self.eval_env, self.controller.test_tasks(), seed=seed)


class TrainingCallback(BaseCallback):
    """Logs the curriculum, evaluates, checkpoints and resets the student on schedule."""

    def __init__(self, session: _Session, start_step: int):
        super().__init__()
        self.s = session
        c = session.config
        self.task_names = session.task_names
        self.next_eval = _next_multiple(start_step, c.effective_eval_every)
        self.next_checkpoint = _next_multiple(start_step, c.effective_checkpoint_every)
        every = c.reset_student_every
        self.next_reset = _next_multiple(start_step, every) if every else None
        self.last_eval_step = self.last_checkpoint_step = -1
        self.bk_seen: dict[str, int] = {}
        self.episodes = CsvLog(
            session.run.episodes_csv,
            ["step", "worker", "return", "length", "success", "truncated", *self.task_names],
        )
        self.evals = CsvLog(
            session.run.evals_csv,
            [
                "step",
                "episodes",
                "mastered_pct",
                "mean_return",
                "std_return",
                "mean_length",
                "n_tasks",
                "wall_time_s",
            ],
        )
        self.eval_tasks = CsvLog(
            session.run.evals_tasks_csv,
            ["step", "task_index", "return", "length", "success", *self.task_names],
        )

    def close(self):
        for log in (self.episodes, self.evals, self.eval_tasks):
            log.close()

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        self.periodic()

    def periodic(self, final: bool = False) -> None:
        step = self.num_timesteps
        if self.next_reset is not None and step >= self.next_reset and not final:
            students.reinitialise(self.model)
            self.logger.record(
                "curriculum/student_resets", step // self.s.config.reset_student_every
            )
            self.next_reset = _next_multiple(step, self.s.config.reset_student_every)
        if step >= self.next_eval or (final and self.last_eval_step != step):
            self.evaluate()
            self.next_eval = _next_multiple(step, self.s.config.effective_eval_every)
        if step >= self.next_checkpoint or (final and self.last_checkpoint_step != step):
            self.log_episodes()
            self.s.save_checkpoint()
            self.last_checkpoint_step = step
            self.next_checkpoint = _next_multiple(step, self.s.config.effective_checkpoint_every)

    def _on_rollout_end(self) -> None:
        self.log_episodes()

    def log_episodes(self) -> None:
        finished = self.s.curriculum_env.pop_finished()
        if not finished:
            return
        for ep in finished:
            self.episodes.write(
                [
                    ep.total_steps,
                    ep.worker,
                    f"{ep.episode_return:.6g}",
                    ep.length,
                    int(ep.success),
                    int(ep.truncated),
                    *(f"{v:.6g}" for v in ep.task),
                ]
            )
        tasks = np.stack([ep.task for ep in finished])
        for name, value in zip(self.task_names, tasks.mean(axis=0)):
            self.logger.record(f"curriculum/mean_task/{name}", float(value))
        self.logger.record(
            "curriculum/episode_return", float(np.mean([e.episode_return for e in finished]))
        )
        self.logger.record("curriculum/success_rate", float(np.mean([e.success for e in finished])))
        self.logger.record("curriculum/episodes", self.s.curriculum_env.episodes_done)
        for key, value in self.teacher_scalars().items():
            self.logger.record(f"curriculum/teacher/{key}", value)

    def teacher_scalars(self) -> dict[str, float]:
        """Mean of each scalar book-keeping series of the teacher (ALPs, losses, KL, ...) over
        the entries added since the last log, for TensorBoard."""
        teacher = getattr(self.s.controller, "teacher", None)
        out = {}
        for key, values in (getattr(teacher, "bk", None) or {}).items():
            start = self.bk_seen.get(key, 0)
            new = [v for v in values[start:] if _is_number(v)]
            self.bk_seen[key] = len(values)
            if new:
                out[key] = float(np.mean(new))
        return out

    def evaluate(self) -> None:
        step = self.num_timesteps
        result = self.s.run_eval(seed=self.s.config.seed + EVAL_SEED_OFFSET)
        summary = result.summary()
        self.evals.write(
            [
                step,
                self.s.curriculum_env.episodes_done,
                f"{summary['mastered_pct']:.4g}",
                f"{summary['mean_return']:.6g}",
                f"{summary['std_return']:.6g}",
                f"{summary['mean_length']:.6g}",
                summary["n_tasks"],
                f"{self.s.wall_time():.1f}",
            ]
        )
        for i, (task, ret, length, success) in enumerate(
            zip(result.tasks, result.returns, result.lengths, result.successes)
        ):
            self.s.controller.record_test_episode(task, ret, length, bool(success))
            self.eval_tasks.write(
                [step, i, f"{ret:.6g}", int(length), int(success), *(f"{v:.6g}" for v in task)]
            )
        self.logger.record("eval/mastered_pct", summary["mastered_pct"])
        self.logger.record("eval/mean_return", summary["mean_return"])
        self.logger.record("curriculum/mastered_pct", summary["mastered_pct"])
        self.logger.dump(step)
        self.last_eval_step = step
        if self.s.config.verbose:
            print(
                f"[acl3d] step {step}: {summary['mastered_pct']:.1f}% mastered, mean return {summary['mean_return']:.1f}",
                flush=True,
            )


def _next_multiple(step: int, every: int) -> int:
    return (step // every + 1) * every


def _is_number(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


# ---------------------------------------------------------------------- public API
def train(config: TrainConfig | dict | None = None, *, resume=None, **overrides) -> TrainResult:
    """Train a student on a teacher's curriculum; or continue `resume` (a run directory).

    `overrides` set config fields (`train(teacher="alp-gmm", steps=10_000, out="runs/x")`). On
    resume the saved config is used; only `steps` (to extend a run) and runtime options
    (progress_bar, verbose, vec_env, start_method, torch_threads, eval_envs) may be changed.
    """
    if resume is not None:
        run = RunDir(resume)
        saved = TrainConfig.from_dict(run.read_config())
        allowed = {
            "steps",
            "progress_bar",
            "verbose",
            "vec_env",
            "start_method",
            "torch_threads",
            "eval_envs",
        }
        changed = {k: v for k, v in dict(config or {}, **overrides).items() if v is not None}
        bad = sorted(
            k for k, v in changed.items() if k not in allowed and getattr(saved, k, v) != v
        )
        if bad:
            raise ValueError(
                f"cannot change {bad} when resuming; only {sorted(allowed)} may change"
            )
        config = dataclasses.replace(saved, **{k: v for k, v in changed.items() if k in allowed})
        # Extending a run keeps its evaluation/snapshot schedule (defaults scale with steps).
        resolved = run.read_section("resolved")
        config = dataclasses.replace(
            config,
            eval_every=config.eval_every or resolved["eval_every"],
            checkpoint_every=config.checkpoint_every or resolved["checkpoint_every"],
            periodical_samples_every=config.periodical_samples_every
            if config.periodical_samples_every is not None
            else resolved["periodical_samples_every"],
        )
        resume_from = run.latest_checkpoint()
    else:
        if isinstance(config, TrainConfig):
            config = dataclasses.replace(config, **overrides)
        else:
            config = TrainConfig.from_dict(dict(config or {}, **overrides))
        if not config.out:
            raise ValueError("out (the run directory) is required")
        run = RunDir(config.out)
        run.check_new()
        resume_from = None
    validate(config)
    torch.set_num_threads(config.torch_threads)
    session = _Session(config, run, resume_from)  # builds the controller: fails before any worker
    sections = {
        "student_hyperparameters": session.params,
        "resolved": {
            "eval_every": config.effective_eval_every,
            "checkpoint_every": config.effective_checkpoint_every,
            "periodical_samples_every": config.effective_periodical_samples,
        },
    }
    if resume_from is None:
        run.create(config.to_dict(), **sections)
    else:
        run.write_config(config.to_dict(), **sections)
    return _run(session, config, run, resume_from)


def _interrupt_on_sigterm(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


def _run(
    session: _Session, config: TrainConfig, run: RunDir, resume_from: Path | None
) -> TrainResult:
    run.set_status("running")
    callback = None
    # Batch schedulers stop jobs with SIGTERM: end like Ctrl-C, with the status written.
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _interrupt_on_sigterm) if in_main else None
    try:
        with session:
            session.build_student()
            model = session.model
            start = int(model.num_timesteps)
            if resume_from is not None:
                for path in (run.evals_csv, run.evals_tasks_csv, run.episodes_csv):
                    truncate_csv(path, "step", start)
            if "value_estimator" in session.controller.needs:
                session.controller.set_value_estimator(
                    students.value_estimator(model, session.normalize_obs())
                )
            if start >= config.steps:
                raise ValueError(
                    f"the run already has {start} steps; pass a larger steps value to extend it"
                )
            callback = TrainingCallback(session, start)
            model.learn(
                total_timesteps=config.steps - start,
                callback=callback,
                progress_bar=config.progress_bar,
                reset_num_timesteps=resume_from is None,
                tb_log_name="train",
            )
            callback.periodic(final=True)
            model.save(run.final_model)
            if session.vecnorm is not None:
                ckpt.save_normalization(session.vecnorm, run.final_model)
            session.controller.dump(str(run.teacher_prefix))
            final = _last_eval(run)
    except KeyboardInterrupt:
        run.set_status("interrupted", latest_checkpoint=run.latest_checkpoint_name())
        raise
    except BaseException as exc:
        run.set_crashed(exc)
        raise
    finally:
        if callback is not None:
            callback.close()
        if in_main:
            signal.signal(signal.SIGTERM, previous)
    run.set_status("finished", steps=int(model.num_timesteps))
    return TrainResult(run.path, int(model.num_timesteps), final)


def _last_eval(run: RunDir) -> dict[str, float] | None:
    from acl3d.training.run_dir import read_csv

    cols = read_csv(run.evals_csv)
    if not cols or not cols["step"]:
        return None
    return {k: v[-1] for k, v in cols.items()}
