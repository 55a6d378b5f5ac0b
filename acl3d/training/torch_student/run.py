"""One training run of a torch-native student on a `TensorVectorEnv`, resumable bit for bit.

The run directory is the one the SB3 students write (config.yaml, status, episodes.csv,
evals.csv, evals_tasks.csv, TensorBoard under RUN/tb, checkpoints, final_model.zip, the teacher
dump), so `analyze`, `report`, `render --model` and campaigns read it unchanged. The loop:
a rollout of `num_steps_per_env` steps on every world, one PPO update, then the periodic work
(evaluation, the episode log, a checkpoint) at the first update at or past each multiple of its
period, and once more at the end. The teacher learns finished episodes and draws the worlds'
next tasks in rounds (`CurriculumRounds`): on the CPU batched env at every step that ends an
episode, before the world's next task is drawn; on the many-world simulation a round draws
tasks ahead and learns the episodes of several steps at once.

A checkpoint holds every world's running episode, the last observations, the tasks drawn ahead
and the episodes waiting for the next round, the student (weights,
normalisers, optimiser, adaptive learning rate, reward statistics), the controller and the
global RNG states (CUDA's too), so a run killed at any point continues from its newest
checkpoint exactly as if it had not stopped (on the CPU; on a GPU it continues the run).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import torch

from acl3d import provenance
from acl3d.atomic_files import atomic_replace, atomic_state_files, temp_prefix
from acl3d.envs.many_worlds import check_many_worlds, many_worlds
from acl3d.envs.tensor_vector import CpuTensorVectorEnv, TensorVectorEnv
from acl3d.run_format.tables import CsvLog, truncate_csv
from acl3d.teachers.state_files import load_state, save_state
from acl3d.training import checkpoint as ckpt
from acl3d.training.config import (
    TrainConfig,
    excludes_exploratory,
    fixed_settings,
    uses_many_worlds,
)
from acl3d.training.run_dir import RunDir
from acl3d.training.session import probe_run
from acl3d.training.student_settings import student_params
from acl3d.training.torch_student import rsl_ppo
from acl3d.training.torch_student.curriculum_rounds import CurriculumRounds, reserve_for
from acl3d.training.torch_student.eval_queue import EvaluationQueue, Pending
from acl3d.training.torch_student.evaluation import ManyWorldEvaluator, WorldEvaluator
from acl3d.training.torch_student.phase_times import PhaseTimes

EPISODE_COLUMNS = ("step", "worker", "return", "length", "success", "truncated")


class TorchRun:
    """Builds the worlds, student and controller of one (new or resumed) run and trains it."""

    def __init__(self, config: TrainConfig, run: RunDir, resume_from: Path | None):
        self.config, self.run, self.resume_from = config, run, resume_from
        self.task_names, self.controller = probe_run(config)
        self.params = student_params(config)
        self.exclude_exploratory = excludes_exploratory(config)
        self.device = torch.device("cpu" if config.device == "auto" else config.device)
        self.warp = uses_many_worlds(config)
        if self.device.type != "cpu" and not self.warp:
            raise ValueError(
                f"vec_env={config.vec_env!r} with device={config.device!r}; valid on a GPU: "
                "vec_env warp or auto (the CPU batched env's worlds live on the CPU)"
            )
        if self.warp:
            check_many_worlds(config.env)
        self.times = PhaseTimes()
        reserve = reserve_for(config.n_envs, self.warp)
        self.curriculum = CurriculumRounds(self.controller, self.times, reserve, config.n_envs)
        self.started, self.previous_wall_time = time.perf_counter(), 0.0
        self.steps: int | None = None  # the steps trained, once provenance.json has its segment
        self.pending: list[Pending] = []  # evaluations a checkpoint left waiting
        self.last_eval = -1  # the step of the latest evaluation (frozen policy), -1: none

    def device_name(self) -> str:
        """The device the student and worlds run on, with the GPU's model (runs on two GPU models
        need not agree step for step) and the simulation it steps."""
        name = str(self.device)
        if self.device.type == "cuda":
            name += f" ({torch.cuda.get_device_name(self.device)})"
        return f"{name}, vec_env {'warp' if self.warp else 'batched'}"

    def wall_time(self) -> float:
        return self.previous_wall_time + time.perf_counter() - self.started

    # ------------------------------------------------------------------ building
    def _build(self) -> None:
        c = self.config
        self.env: TensorVectorEnv
        if self.warp:
            self.env = many_worlds(
                c.env, c.n_envs, self.device, curriculum=self.curriculum, body=c.body,
                **c.env_kwargs,
            )  # fmt: skip
            # no more copies of the test set than the run will have evaluations
            copies = min(c.effective_eval_together, c.steps // c.effective_eval_every + 1)
            self.evaluator = ManyWorldEvaluator(
                c.env, c.body, c.env_kwargs, self.controller.test_tasks(), c.eval_seed,
                c.eval_envs, self.device, copies,
            )  # fmt: skip
        else:
            self.env = CpuTensorVectorEnv(
                c.env, c.n_envs, curriculum_sync=self.curriculum, body=c.body, **c.env_kwargs
            )
            self.evaluator = WorldEvaluator(
                c.env, c.body, c.env_kwargs, self.controller.test_tasks(), c.eval_seed, c.eval_envs
            )
        self.student = rsl_ppo.RslPPO(
            self.params, self.env.observation_size, self.env.action_size, c.n_envs,
            self.device, self.env.action_low, self.env.action_high, self.exclude_exploratory,
        )  # fmt: skip
        if "value_estimator" in self.controller.needs:
            self.controller.set_value_estimator(self._values, self._episode_values)

    def _values(self, states: np.ndarray) -> np.ndarray:
        """The critic's values of a batch of states (a teacher's value estimator)."""
        return self._episode_values([states])[0]

    def _episode_values(self, episodes: list[np.ndarray]) -> list[np.ndarray]:
        """The critic's values of each episode's states: one copy to the device, one pass of
        the critic over all of them and one copy back (a pass an episode cost a dozen kernel
        launches each, ~10k episodes in a 2M-step run at 4,096 worlds). An episode's values
        can differ in their last bits with the episodes that end beside it, which the run's
        seed fixes: runs still repeat and resume exactly."""
        states = [np.atleast_2d(s) for s in episodes]
        sizes = [len(s) for s in states]
        together = torch.as_tensor(np.concatenate(states), dtype=torch.float32)
        values = self.student.value(together.to(self.student.device))
        return np.split(values.cpu().numpy(), np.cumsum(sizes)[:-1])

    def _restore(self, folder: Path) -> tuple[torch.Tensor, int]:
        state = torch.load(folder / "student.pt", weights_only=False)
        self.student.load_state_dict(state["student"])
        self.pending = [
            Pending.from_state(p, self.student) for p in state.get("pending_evaluations", [])
        ]
        runtime = load_state(folder / "runtime")
        self.controller.load_state_dict(load_state(folder / "controller"))
        self.env.set_state(runtime["env"])
        self.curriculum.load_state(runtime.get("curriculum"))
        progress = load_state(folder / "progress")
        # a checkpoint of the last step may follow that step's evaluation: not done twice
        self.last_eval = int(progress.get("last_eval", -1))
        self.curriculum.episodes_done = int(progress["episodes_done"])
        self.previous_wall_time = float(progress.get("wall_time_s", 0.0))
        ckpt.set_rng_state(load_state(folder / "rng"))
        if state.get("cuda_rng") is not None:
            torch.cuda.set_rng_state_all(state["cuda_rng"])
        return torch.from_numpy(runtime["last_obs"]).to(self.device), int(progress["num_timesteps"])

    # ------------------------------------------------------------------ training
    def train(self, target: int, sections: dict, overwrite: bool) -> int:
        """Train to `target` steps; returns the steps trained. Writes the run's start first."""
        c, run = self.config, self.run
        torch.manual_seed(c.seed)
        np.random.seed(c.seed)
        self._build()
        try:
            if self.resume_from is None:
                run.create(c.to_dict(), overwrite=overwrite, **sections)
                obs, steps = self.env.reset(seed=c.seed).to(self.device), 0
            else:
                obs, steps = self._restore(self.resume_from)
                run.remove_temp_files()
                run.restart_from(self.resume_from)
                run.update_config(c.to_dict(), **sections)
                truncate_csv(run.episodes_csv, "step", steps)
                # evaluations still waiting at the checkpoint are played again
                played = min([p.step - 1 for p in self.pending], default=steps)
                for path in (run.evals_csv, run.evals_tasks_csv):
                    truncate_csv(path, "step", played)
            run.set_status("running", pid=os.getpid())
            event = "start" if self.resume_from is None else "resume"
            provenance.record(run.path, event, steps, self.device_name())
            self.steps = steps
            return self._loop(obs, steps, target)
        finally:
            self.env.close()
            self.evaluator.close()

    def _loop(self, obs: torch.Tensor, steps: int, target: int) -> int:
        c, n = self.config, self.config.n_envs
        self.episodes = CsvLog(self.run.episodes_csv, [*EPISODE_COLUMNS, *self.task_names])
        self.tb = _writer(self.run.tb / "train_1") if c.tensorboard else None
        self.evaluations = EvaluationQueue(
            self.evaluator, self.run, self.task_names, self.controller, c, self.tb, self.pending
        )
        every_eval, every_ckpt = c.effective_eval_every, c.effective_checkpoint_every
        next_eval, next_ckpt = _next(steps, every_eval), _next(steps, every_ckpt)
        every_reset = c.reset_student_every
        next_reset = _next(steps, every_reset) if every_reset else None
        last_ckpt = steps if self.resume_from is not None else -1  # the one resumed from
        times = self.times
        while steps < target:
            tick = time.perf_counter()
            with times.phase("collect"), torch.inference_mode():
                for _ in range(self.student.steps_per_env):
                    actions = self.student.act(obs)
                    before = obs.clone() if self.curriculum.learns_steps else obs
                    running = self._exploratory()  # the flags of the episodes this step plays
                    obs, rewards, terminated, truncated, extras = self.env.step(actions)
                    self.student.record(
                        rewards, terminated, truncated, extras["final_obs"], running
                    )
                    self.curriculum.record_steps(
                        before, actions, rewards, terminated | truncated, extras["final_obs"]
                    )
                    steps += n
                    self.steps = steps
                    self.controller.maybe_sample_periodically(steps)
            collect = time.perf_counter() - tick
            with times.phase("update"):
                losses = self.student.update(obs)
                if next_reset is not None and steps >= next_reset:  # a forgetting student
                    self.student.reinitialise()
                    next_reset = _next(steps, every_reset)
                    if self.tb is not None:
                        self.tb.add_scalar("curriculum/student_resets", steps // every_reset, steps)
            self._log_update(steps, losses, collect, time.perf_counter() - tick)
            if steps >= next_eval:
                with times.phase("evaluate"):
                    self._freeze_policy(steps)
                    self.evaluations.play(at_least=c.effective_eval_together)
                next_eval = _next(steps, every_eval)
            with times.phase("records"):
                self._log_episodes(steps)
                if steps >= next_ckpt:
                    self._checkpoint(steps, obs)
                    last_ckpt, next_ckpt = steps, _next(steps, every_ckpt)
        with times.phase("evaluate"):
            if self.last_eval != steps:
                self._freeze_policy(steps)
            self.evaluations.play(at_least=1)
        with times.phase("records"):
            self._log_episodes(steps)
            if last_ckpt != steps:
                self._checkpoint(steps, obs)
            self.curriculum.learn_waiting()  # after the checkpoint: a resume finds them waiting
            self._save_policy(self.run.final_model)
        if c.verbose:
            print(f"[acl3d] wall time by phase: {times.summary()}", flush=True)
        if self.tb is not None:
            self.tb.close()
        return steps

    def _exploratory(self) -> torch.Tensor | None:
        if not self.student.exclude_exploratory:
            return None
        return torch.from_numpy(self.curriculum.exploratory.copy()).to(self.device)

    # ------------------------------------------------------------------ periodic work
    def _log_update(self, steps: int, losses: dict, collect: float, total: float) -> None:
        if self.tb is None:
            return
        for key, value in losses.items():
            self.tb.add_scalar(f"train/{key}_loss", value, steps)
        self.tb.add_scalar("train/learning_rate", self.student.learning_rate, steps)
        self.tb.add_scalar("train/std", self.student.action_std, steps)
        rollout = self.student.steps_per_env * self.config.n_envs
        self.tb.add_scalar("time/fps", rollout / max(total, 1e-9), steps)
        self.tb.add_scalar("time/collection_share", collect / max(total, 1e-9), steps)

    def _log_episodes(self, steps: int) -> None:
        batches, self.curriculum.finished = self.curriculum.finished, []
        if not batches:
            return
        self.episodes.write_rows(
            [at, i, f"{r:.6g}", n, int(ok), int(cut), *(f"{v:.6g}" for v in task)]
            for b in batches
            for at, i, r, n, ok, cut, task in zip(
                b.total_steps, b.env_ids, b.returns, b.lengths, b.successes, b.truncated, b.tasks
            )
        )
        if self.tb is not None:
            returns = np.concatenate([b.returns for b in batches])
            successes = np.concatenate([b.successes for b in batches])
            self.tb.add_scalar("curriculum/episode_return", returns.mean(), steps)
            self.tb.add_scalar("curriculum/success_rate", successes.mean(), steps)
            self.tb.add_scalar("curriculum/episodes", self.curriculum.episodes_done, steps)

    def _freeze_policy(self, steps: int) -> None:
        """The evaluation of step `steps`: its policy waits for a pass (`eval_together`)."""
        snapshot = self.student.snapshot()
        self.last_eval = steps
        self.evaluations.add(
            Pending(steps, self.curriculum.episodes_done, self.wall_time(), snapshot)
        )

    def _checkpoint(self, steps: int, obs: torch.Tensor) -> None:
        def write(folder: Path) -> None:
            self.student.save_policy(folder / "model.zip")
            cuda = torch.cuda.get_rng_state_all() if torch.cuda.is_initialized() else None
            torch.save(
                {"student": self.student.state_dict(), "cuda_rng": cuda,
                 "pending_evaluations": self.evaluations.state()},
                folder / "student.pt",
            )  # fmt: skip
            runtime = {
                "env": self.env.get_state(),
                "last_obs": obs.cpu().numpy(),
                "curriculum": self.curriculum.state(),
            }
            save_state(folder / "runtime", runtime)
            save_state(folder / "controller", self.controller.state_dict())
            save_state(folder / "rng", ckpt.rng_state())
            progress = {
                "num_timesteps": steps,
                "episodes_done": self.curriculum.episodes_done,
                "last_eval": self.last_eval,
                "time": time.time(),
                "wall_time_s": self.wall_time(),
                "config": fixed_settings(self.config),
            }
            save_state(folder / "progress", progress)

        self.run.write_checkpoint(steps, write)
        self._dump_teacher()

    def _dump_teacher(self) -> None:
        atomic_state_files(self.run.teacher_prefix, lambda tmp: self.controller.dump(str(tmp)))

    def _save_policy(self, final: Path) -> None:
        tmp = temp_prefix(final.with_suffix("")).with_suffix(".zip")
        self.student.save_policy(tmp)
        atomic_replace(tmp, final)
        self._dump_teacher()


def _next(step: int, every: int) -> int:
    return (step // every + 1) * every


def _writer(path: Path):
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter(str(path))
