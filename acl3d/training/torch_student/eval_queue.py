"""A torch-native run's evaluations: the policy frozen when an evaluation falls due, snapshots
played `eval_together` at a time (`ChunkedEvaluator`), each one's results written to evals.csv,
evals_tasks.csv, TensorBoard and the teacher's test records as if played when due. Snapshots
still waiting go into checkpoints, so a killed run plays them after its resume."""

from __future__ import annotations

from typing import NamedTuple

from acl3d.run_format.tables import CsvLog
from acl3d.training.torch_student.rsl_ppo import PolicySnapshot

EVAL_COLUMNS = ("step", "episodes", "mastered_pct", "mean_return", "std_return", "mean_length",
                "n_tasks", "wall_time_s")  # fmt: skip


class Pending(NamedTuple):
    """An evaluation waiting for a pass: the step, episodes and wall time it belongs to, and the
    policy of that step."""

    step: int
    episodes: int
    wall_time_s: float
    policy: PolicySnapshot

    def state(self) -> dict:
        return {"step": self.step, "episodes": self.episodes, "wall_time_s": self.wall_time_s,
                "weights": self.policy.state_dict()}  # fmt: skip

    @classmethod
    def from_state(cls, state: dict, student) -> Pending:
        """Back from `state()`, the policy rebuilt by `student.snapshot(weights)`."""
        policy = student.snapshot(state["weights"])
        return cls(int(state["step"]), int(state["episodes"]), float(state["wall_time_s"]), policy)


class EvaluationQueue:
    """Evaluations of one run (see the module docstring); `tb` a TensorBoard writer or None."""

    def __init__(self, evaluator, run, task_names, controller, config, tb, pending=()):
        self.evaluator, self.controller, self.config, self.tb = evaluator, controller, config, tb
        self.evals = CsvLog(run.evals_csv, list(EVAL_COLUMNS))
        self.eval_tasks = CsvLog(
            run.evals_tasks_csv, ["step", "task_index", "return", "length", "success", *task_names]
        )
        self.pending: list[Pending] = list(pending)

    def add(self, pending: Pending) -> None:
        self.pending.append(pending)

    def play(self, at_least: int) -> None:
        """Play the waiting snapshots in one pass if at least `at_least` (and one) wait."""
        if len(self.pending) < max(at_least, 1):
            return
        waiting, self.pending = self.pending, []
        if self.config.verbose:
            print(f"[acl3d] evaluating the policies of step(s) {[p.step for p in waiting]} on "
                  f"{len(self.evaluator.tasks)} test tasks ({self.evaluator.num_worlds} worlds "
                  "each)...", flush=True)  # fmt: skip
        results = self.evaluator.run([p.policy for p in waiting], self.config.eval_stochastic)
        for pending, result in zip(waiting, results, strict=True):
            self._write(pending, result)

    def state(self) -> list[dict]:
        """The waiting snapshots, for a checkpoint."""
        return [p.state() for p in self.pending]

    def _write(self, pending: Pending, result) -> None:
        steps, s = pending.step, result.summary()
        self.evals.write(
            [steps, pending.episodes, f"{s['mastered_pct']:.4g}", f"{s['mean_return']:.6g}",
             f"{s['std_return']:.6g}", f"{s['mean_length']:.6g}", s["n_tasks"],
             f"{pending.wall_time_s:.1f}"]
        )  # fmt: skip
        rows = []
        for i, (task, ret, length, ok) in enumerate(
            zip(result.tasks, result.returns, result.lengths, result.successes)
        ):
            self.controller.record_test_episode(task, ret, length, bool(ok))
            rows.append([steps, i, f"{ret:.6g}", int(length), int(ok), *(f"{v:.6g}" for v in task)])
        self.eval_tasks.write_rows(rows)
        if self.tb is not None:
            self.tb.add_scalar("eval/mastered_pct", s["mastered_pct"], steps)
            self.tb.add_scalar("eval/mean_return", s["mean_return"], steps)
        if self.config.verbose:
            print(f"[acl3d] step {steps}: {s['mastered_pct']:.1f}% mastered, mean return "
                  f"{s['mean_return']:.1f}", flush=True)  # fmt: skip
