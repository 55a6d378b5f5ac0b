"""The session of one run: its vec envs, student and teacher controller, and their checkpoints.

A checkpoint holds everything that decides what happens next, so a resumed run continues bit for
bit: SB3's zip (weights, optimisers, counters), the VecNormalize statistics and running returns,
the replay buffer, the controller (teacher state and records), every worker env's state and task
queue, SB3's last observations and episode windows, and the torch/numpy/python RNG states.
Everything except SB3's own zip is JSON + NPZ.
"""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import VecNormalize

from acl3d import validation as check
from acl3d.atomic_files import atomic_replace, atomic_state_files, removed_on_failure, temp_prefix
from acl3d.envs.task_env import TaskEnv, task_env
from acl3d.run_format.checkpoints import DamagedCheckpoint, verify_manifest
from acl3d.teachers.state_files import load_state, save_state
from acl3d.training import checkpoint as ckpt
from acl3d.training import students
from acl3d.training.config import TrainConfig, excludes_exploratory, fixed_settings
from acl3d.training.curriculum import CurriculumVecEnv
from acl3d.training.evaluation import EvalResult, evaluate, make_predict
from acl3d.training.run_dir import RunDir, read_state
from acl3d.training.student_settings import student_params
from acl3d.training.workers import env_keywords, make_env, make_vec_env

if TYPE_CHECKING:
    from acl3d.teachers.controller import TeacherController


def build_controller(config: TrainConfig, task_space, profile=None):
    """The teacher controller a run with `config` uses (test set and snapshots included);
    `profile` is the env's `curriculum_profile` (reward bounds, expert knowledge, test sets)."""
    from acl3d.teachers.controller import TeacherController

    return TeacherController(
        config.teacher,
        task_space,
        config.seed,
        teacher_params=dict(config.teacher_params) or None,
        expert_knowledge=config.expert_knowledge,
        profile=profile,
        scale_reward=config.scale_reward,
        shuffle_dimensions=config.shuffle_dimensions,
        test_set=config.test_set,
        nb_test_episodes=config.nb_test_episodes,
        keep_periodical_task_samples=config.effective_periodical_samples,
        total_steps=int(config.steps),
    )


def probe_env(config: TrainConfig):
    """One env of the run, built to check its name, body and `env_kwargs` (named in the error)."""
    try:
        return make_env(config.env, config.body, config.env_kwargs)
    except (TypeError, ValueError) as exc:
        raise env_kwargs_error(config, exc) from None


def env_kwargs_error(config: TrainConfig, exc: Exception) -> Exception:
    """The env's rejection of an `env_kwargs` entry as `env_kwargs['NAME']=VALUE; valid: ...`
    (a TypeError for an unknown name lists the names the env takes); other errors unchanged."""
    text = str(exc)
    unknown = re.search(r"unexpected keyword argument '(\w+)'", text)
    if unknown and unknown[1] in config.env_kwargs:
        name = unknown[1]
        return check.fail(
            f"env_kwargs[{name!r}]",
            config.env_kwargs[name],
            f"keyword arguments of {config.env}: {', '.join(env_keywords(config.env))}",
        )
    for name in config.env_kwargs:
        if text.startswith(f"{name}="):
            return ValueError(f"env_kwargs[{name!r}]{text[len(name) :]}")
    return exc


def probe_task_space(config: TrainConfig, env=None):
    """(task space with the run's teacher bounds applied, the env's curriculum profile); a
    ValueError naming the env if it is not a `TaskEnv`."""
    own = env is None
    env = probe_env(config) if own else env
    try:
        inner = task_env(env)
        task_space, profile = inner.task_space, inner.curriculum_profile
        if config.bounds:
            task_space = task_space.with_bounds(**{k: tuple(v) for k, v in config.bounds.items()})
            check_bounds(inner, task_space, config)
    finally:
        if own:
            env.close()
    return task_space, profile


def check_bounds(env: TaskEnv, task_space, config: TrainConfig) -> None:
    """Both ends of every bounded parameter must be buildable (the env's `set_task` check), so
    that no task the teacher samples fails after the run started, or after `overwrite` deleted
    the run it replaces."""
    for p in task_space.parameters:
        if p.name not in config.bounds:
            continue
        for end in (p.low, p.high):
            try:
                env.set_task({p.name: end[0] if p.dims == 1 else np.asarray(end)})
            except ValueError as exc:
                why = " ".join(str(exc).split())
                raise check.fail(
                    f"bounds[{p.name!r}]",
                    config.bounds[p.name],
                    f"a (min, max) pair {config.env} can build ({why})",
                ) from None


def check_test_tasks(env, tasks, task_names: list[str]) -> None:
    """Every test task must be playable by the env (its `set_task` check), so that a bad test
    set fails at start, not at the first evaluation after hours of training."""
    set_task = task_env(env).set_task
    for i, task in enumerate(tasks):
        try:
            set_task(task)
        except ValueError as exc:
            shown = dict(zip(task_names, np.round(np.asarray(task, dtype=float), 6).tolist()))
            why = " ".join(str(exc).split())  # one line: the env may show an array
            raise ValueError(f"test set: task {i} {shown} cannot be played: {why}") from None


def probe_run(
    config: TrainConfig, check_spaces: bool = False
) -> tuple[list[str], TeacherController]:
    """(flat task names, teacher controller) of a run, from one env of it: the env's settings,
    the teacher's bounds and every test task checked before the run writes anything;
    `check_spaces`: also the SB3 algorithm against the env's action space."""
    env = probe_env(config)
    try:
        if check_spaces:
            students.check_action_space(config.student, env.observation_space, env.action_space)
        task_space, profile = probe_task_space(config, env)
        task_names = task_space.flat_names()
        with np.errstate(over="ignore"):  # a test task beyond float32 is refused just below
            controller = build_controller(config, task_space, profile)
        check_test_tasks(env, controller.test_tasks(), task_names)
    finally:
        env.close()
    return task_names, controller


def verify_checkpoint(folder: Path, config: TrainConfig) -> None:
    """Check every file of a checkpoint against the size and SHA-256 its manifest recorded
    before any is used: `DamagedCheckpoint` names the first missing, truncated, corrupt or
    edited one. A config that differs from the one the checkpoint was trained with (an edited
    config.yaml) is a ValueError."""
    verify_manifest(folder)
    try:
        progress = read_state(folder / "progress")
    except ValueError as exc:
        raise DamagedCheckpoint(str(exc)) from None
    if not isinstance(progress.get("config"), dict):
        raise DamagedCheckpoint(f"{folder.name}: progress records no training settings")
    check_fixed_settings(config, progress["config"], folder.name)


def check_fixed_settings(config: TrainConfig, trained: dict, checkpoint: str) -> None:
    """The run's config must still be the one its checkpoint was trained with (config.yaml may
    have been edited)."""
    now = fixed_settings(config)
    for name in sorted(set(trained) | set(now)):
        if trained.get(name) != now.get(name):
            raise ValueError(
                f"config {name}={now.get(name)!r} differs from {trained.get(name)!r}, the value "
                f"checkpoint {checkpoint} was trained with; a run keeps its {name} for life "
                f"(restore {trained.get(name)!r} in config.yaml, or start a new run)"
            )


class Session:
    """Builds the envs, student and controller of one (new or resumed) run.

    Constructing it checks the teacher and student settings without starting any worker; the
    envs start in `__enter__`, the student in `build_student()`.
    """

    def __init__(self, config: TrainConfig, run: RunDir, resume_from: Path | None = None):
        self.config, self.run, self.resume_from = config, run, resume_from
        self.task_names, self.controller = probe_run(config, check_spaces=True)
        self.params = student_params(config)
        self.exclude_exploratory = excludes_exploratory(config)
        self.train_env = self.eval_env = self.curriculum_env = self.vecnorm = None
        self.model = None
        self.started = time.perf_counter()
        self.previous_wall_time = 0.0

    def _vec_env(self, n_envs: int):
        c = self.config
        return make_vec_env(
            c.env,
            c.body,
            n_envs,
            c.env_kwargs,
            c.vec_env,
            c.start_method,
            envs_per_worker=None if c.envs_per_worker is None else min(c.envs_per_worker, n_envs),
        )

    def __enter__(self):
        try:
            self._start_envs()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def _start_envs(self) -> None:
        try:
            venv = self._vec_env(self.config.n_envs)
        except (TypeError, ValueError) as exc:
            raise env_kwargs_error(self.config, exc) from None
        self.curriculum_env = CurriculumVecEnv(venv, self.controller)
        env = self.curriculum_env
        if students.uses_vecnormalize(self.config.student):
            env = self.vecnorm = VecNormalize(
                env,
                norm_obs=True,
                norm_reward=True,
                clip_obs=10.0,
                clip_reward=10.0,
                gamma=self.params.get("gamma", 0.99),
            )
        self.train_env = env
        self.eval_env = self._vec_env(self.config.effective_eval_envs)

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

    # ------------------------------------------------------------------ the student
    def build_student(self) -> None:
        """A new student, or the checkpoint's with every piece of state restored; then give
        teachers that need it the student's value function (SPDL and other value-based ones)."""
        c = self.config
        if self.resume_from is None:
            self.model = students.build(
                c.student,
                self.params,
                self.train_env,
                c.seed,
                self.tensorboard_dir(),
                c.device,
                exclude_exploratory=self.exclude_exploratory,
            )
        else:
            self._restore(self.resume_from)
        if "value_estimator" in self.controller.needs:
            self.controller.set_value_estimator(
                students.value_estimator(self.model, self.normalize_obs())
            )

    def tensorboard_dir(self) -> str | None:
        return str(self.run.tb) if self.config.tensorboard else None

    def _restore(self, folder: Path) -> None:
        c = self.config
        model = self.model = students.load(
            c.student, folder / "model.zip", env=self.train_env, device=c.device
        )
        model.tensorboard_log = self.tensorboard_dir()
        runtime = load_state(folder / "runtime")
        if self.vecnorm is not None:
            ckpt.load_normalization_into(self.vecnorm, folder / "model.zip")
            ckpt.set_normalization_runtime(self.vecnorm, runtime["vecnormalize"])
        if (folder / "replay_buffer.npz").exists():
            ckpt.load_replay_buffer(model.replay_buffer, folder / "replay_buffer.npz")
        self.controller.load_state_dict(load_state(folder / "controller"))
        self.curriculum_env.set_state(runtime["envs"])
        ckpt.set_algorithm_state(model, runtime["algorithm"])
        if any(worker["env"] is None for worker in runtime["envs"]["workers"]):
            print(
                f"[acl3d] {c.env} has no get_state(): the episodes running at the checkpoint "
                "restart from a reset, so this resume is not bit-exact",
                file=sys.stderr,
            )
            model._last_obs = None  # SB3 resets the envs (each pulls its queued task)
            self.train_env.seed(c.seed + int(model.num_timesteps))
        progress = load_state(folder / "progress")
        self.previous_wall_time = float(progress.get("wall_time_s", 0.0))
        ckpt.set_rng_state(load_state(folder / "rng"))  # last: nothing above may draw after it

    def wall_time(self) -> float:
        """Seconds of training so far, over all sessions of the run."""
        return self.previous_wall_time + time.perf_counter() - self.started

    # ------------------------------------------------------------------ checkpoints
    def save_checkpoint(self) -> Path:
        """Write a complete checkpoint of the current step and make it the resume point."""
        folder = self.run.write_checkpoint(int(self.model.num_timesteps), self._write_checkpoint)
        self.dump_teacher()
        return folder

    def _write_checkpoint(self, folder: Path) -> None:
        model = self.model
        model.save(folder / "model.zip")
        runtime = {
            "algorithm": ckpt.algorithm_state(model),
            "envs": self.curriculum_env.get_state(),
            "vecnormalize": None,
        }
        if self.vecnorm is not None:
            ckpt.save_normalization(self.vecnorm, folder / "model.zip")
            runtime["vecnormalize"] = ckpt.normalization_runtime(self.vecnorm)
        if isinstance(model, OffPolicyAlgorithm) and self.config.save_replay_buffer:
            ckpt.save_replay_buffer(model.replay_buffer, folder / "replay_buffer.npz")
        save_state(folder / "runtime", runtime)
        save_state(folder / "controller", self.controller.state_dict())
        save_state(folder / "rng", ckpt.rng_state())
        progress = {
            "num_timesteps": int(model.num_timesteps),
            "episodes_done": int(self.curriculum_env.episodes_done),
            "time": time.time(),
            "wall_time_s": self.wall_time(),
            "config": fixed_settings(self.config),
        }
        save_state(folder / "progress", progress)

    def dump_teacher(self) -> None:
        """The controller's dump (RUN/teacher.*) for plots, replaced atomically."""
        atomic_state_files(self.run.teacher_prefix, lambda tmp: self.controller.dump(str(tmp)))

    def save_final_model(self) -> None:
        """RUN/final_model.zip (+ its normalisation statistics), each replaced atomically."""
        final = self.run.final_model
        if self.vecnorm is not None:
            atomic_state_files(
                ckpt.normalization_path(final),
                lambda tmp: save_state(tmp, ckpt.normalization_state(self.vecnorm)),
            )
        tmp = temp_prefix(final.with_suffix("")).with_suffix(".zip")
        with removed_on_failure(tmp):
            self.model.save(tmp)
            atomic_replace(tmp, final)

    # ------------------------------------------------------------------ evaluation
    def run_eval(self) -> EvalResult:
        """One pass over the test set with the run's evaluation seed (the same every time)."""
        c = self.config
        predict = make_predict(self.model, not c.eval_stochastic, self.normalize_obs())
        return evaluate(predict, self.eval_env, self.controller.test_tasks(), seed=c.eval_seed)
