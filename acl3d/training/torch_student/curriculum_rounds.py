"""The curriculum of a torch-native run's worlds: the controller learns and draws in rounds.

A teacher call costs a fixed ~0.5 ms (checks, a neighbour search, a mixture draw, records) plus a
little per episode, and a many-world step ends a few episodes: 4,096 worlds called the teacher at
4,483 of their 4,883 steps in a 20M-step run, 3 s of teacher time. So on the many-world simulation
each round draws `reserve` tasks beyond those the resetting worlds need; they serve the next
resets in order, and the episodes that end meanwhile wait to be learnt at the next round. The
teacher then learns each episode a few steps later (at most `reserve` resets later) and draws
tasks from what it knew a few steps earlier, in fewer, larger calls; a round happens at fixed
points of the run (when the drawn tasks run out), so runs repeat and resume exactly. With
`reserve` 0 (every run on the CPU batched env) each sync is a round: learn, then draw exactly
the tasks needed.

A teacher that learns from every step (Robust PLR, ACCEL, Self-Paced: "step_rewards" in its
`needs`) gets every world's transition of each step in one call (`record_steps`), which the
loop makes after the step; the episodes that ended in it are learnt then, after their last
step, and the resetting worlds' next tasks were drawn from what the teacher knew before the
step (as SB3 students' workers get their next task one episode ahead).

`exploratory` holds, per world, whether its running episode plays a level the teacher marked
exploratory (Robust PLR and ACCEL's new and edited levels), which the student leaves out of its
updates.
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from acl3d.envs.episode_statistics import EpisodeBatch
from acl3d.teachers.controller import TeacherController
from acl3d.training.torch_student.phase_times import PhaseTimes

WORLDS_PER_RESERVED_TASK = 64  # many-world runs draw n_envs / 64 tasks ahead (64 at 4,096)


def reserve_for(n_envs: int, many_worlds: bool) -> int:
    """Tasks a round draws ahead for `n_envs` worlds: n_envs / 64, at least 1, on the many-world
    simulation; 0 on the CPU batched env."""
    return max(1, n_envs // WORLDS_PER_RESERVED_TASK) if many_worlds else 0


class CurriculumRounds:
    """The worlds' `CurriculumSync` (see the module docstring); finished episodes also wait in
    `finished` for the episode log, and `episodes_done` counts them."""

    def __init__(
        self, controller: TeacherController, times: PhaseTimes, reserve: int, num_envs: int
    ):
        self.controller, self.times, self.reserve = controller, times, int(reserve)
        self.learns_steps = "step_rewards" in controller.needs
        self.finished: list[EpisodeBatch] = []
        self.episodes_done = 0
        self.exploratory = np.zeros(num_envs, dtype=bool)  # of each world's running episode
        self._waiting: list[EpisodeBatch] = []  # finished, not learnt yet
        self._drawn = np.zeros((0, controller.task_space.dim), dtype=np.float32)  # not handed out
        self._drawn_exploratory = np.zeros(0, dtype=bool)

    def sync(self, finished: EpisodeBatch, env_ids) -> np.ndarray:
        with self.times.phase("teacher"):
            if len(finished):
                self.finished.append(finished)
                self.episodes_done += len(finished)
            if len(finished) and not self.learns_steps:
                self._waiting.append(finished)
            need = len(env_ids)
            if need > len(self._drawn):
                self.learn_waiting()
                more = self.controller.sample_training_tasks(need - len(self._drawn) + self.reserve)
                self._drawn = np.concatenate((self._drawn, more[0]))
                self._drawn_exploratory = np.concatenate((self._drawn_exploratory, more[1]))
            if len(finished) and self.learns_steps:  # learnt after their last steps
                self._waiting.append(finished)
            tasks, self._drawn = self._drawn[:need], self._drawn[need:]
            self.exploratory[np.asarray(env_ids, dtype=np.int64)] = self._drawn_exploratory[:need]
            self._drawn_exploratory = self._drawn_exploratory[need:]
            return tasks

    def record_steps(self, obs, actions, rewards, dones, next_obs) -> None:
        """One step of every world, (N, ...) tensors, for a teacher that learns from steps
        (`next_obs`: an ended episode's final observation), in one call and one copy to the
        host; then the episodes that ended in it are learnt. Nothing for other teachers."""
        if not self.learns_steps:
            return
        with self.times.phase("teacher"):
            arrays = [t.cpu().numpy() for t in (obs, actions, rewards, next_obs, dones)]
            self.controller.record_steps(*arrays)
            self.learn_waiting()

    def learn_waiting(self) -> None:
        """The controller learns the episodes that wait (at a round, or at the end of a run, so
        that its dump holds every episode)."""
        if self._waiting:
            self.controller.record_episodes(EpisodeBatch.concat(self._waiting))
            self._waiting = []

    # ------------------------------------------------------------------ checkpoints
    def state(self) -> dict:
        """The drawn tasks not handed out and the episodes not learnt, for a checkpoint."""
        state = {
            "drawn": self._drawn.copy(),
            "drawn_exploratory": self._drawn_exploratory.copy(),
            "exploratory": self.exploratory.copy(),
        }
        if self._waiting:
            waiting = EpisodeBatch.concat(self._waiting)
            state["waiting"] = {
                f.name: getattr(waiting, f.name)
                for f in fields(EpisodeBatch)
                if getattr(waiting, f.name) is not None
            }
        return state

    def load_state(self, state: dict | None) -> None:
        """Continue from `state()` (None: a checkpoint written before rounds, when nothing
        waited between calls)."""
        dim = self.controller.task_space.dim
        self._drawn = np.zeros((0, dim), np.float32) if state is None else state["drawn"]
        self._drawn = np.asarray(self._drawn, dtype=np.float32).reshape(-1, dim)
        waiting = None if state is None else state.get("waiting")
        self._waiting = [] if waiting is None else [EpisodeBatch(**waiting)]
        # checkpoints written before exploratory flags were kept: no level was exploratory
        flags = {} if state is None else state
        self._drawn_exploratory = np.asarray(
            flags.get("drawn_exploratory", np.zeros(len(self._drawn), bool)), dtype=bool
        )
        self.exploratory[:] = flags.get("exploratory", False)
