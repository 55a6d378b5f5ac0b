"""`TrainConfig`: every option of a training run, and its strict validation.

The CLI, config files and `train()` share one dataclass (this module imports neither torch nor
SB3 until a config is validated, so the CLI's parser stays fast). `validate()` checks names, numbers and
flags without building anything, so a bad option fails in a second with its name, value and the
allowed values; nothing is coerced silently (a count written 2e6 is the only float accepted).
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from typing import Any, Literal

from acl3d import validation as check
from acl3d.teachers.expert_knowledge import LEVELS as EXPERT_KNOWLEDGE
from acl3d.teachers.test_sets import MAX_TASKS as MAX_TEST_TASKS

# Training envs when none are asked for (`TrainConfig.effective_n_envs`): an SB3 student's
# batched env of 16 fills 2 cores; a torch-native student trains fastest on 64 CPU worlds (its
# `fast` preset: 64 x 128-step rollouts, docs/benchmarks.md) and fills a GPU from 4,096.
DEFAULT_N_ENVS = 16
DEFAULT_CPU_WORLDS = 64
DEFAULT_GPU_WORLDS = 4096
TEACHMYAGENT_EVAL_EVERY = 500_000
MIN_DEFAULT_EVAL_EVERY = 50_000
MANY_WORLD_EVALUATIONS = 10  # default evaluations of a run on the many-world simulation
MAX_EVAL_TOGETHER = 64  # evaluations one pass plays side by side (64 copies of the test set)
TEACHMYAGENT_PERIODICAL_SAMPLES = 250_000
# Evaluation envs get their own seed, the same at every evaluation, so successive evaluations
# differ only by the policy (not by the stump-height noise of the test tracks).
EVAL_SEED_OFFSET = 7919
# Bounds that protect the machine (memory, processes, threads) and the seeding libraries.
MAX_TEST_EPISODES = MAX_TEST_TASKS  # a test pass of this many already costs up to 2e8 steps
MAX_SEED = 2**31 - 1  # numpy's legacy seeding takes < 2**32; derived seeds add small offsets
MIN_WORKER_PROCESSES = 16  # worker processes allowed on any machine (else 4 per CPU core)

# TeachMyAgent's protocol per student: its hyperparameters, 20M steps, 100 test tasks, and the
# expert knowledge its tables call "low" (the options given with it still win).
BENCHMARK: dict[str, dict[str, Any]] = {
    student: {
        "student": student,
        "preset": "benchmark",
        "steps": 20_000_000,
        "nb_test_episodes": 100,
        "expert_knowledge": "low",
        "eval_stochastic": student == "ppo",  # TeachMyAgent's PPO samples its test actions
    }
    for student in ("sac", "ppo")
}


@dataclass
class TrainConfig:
    """Every option of a training run (the CLI, config files and `train()` share it)."""

    # The defaults train something sensible on a laptop in minutes (ALP-GMM and a small PPO);
    # BENCHMARK holds TeachMyAgent's student settings (`acl3d train --benchmark sac`).
    env: str = "stump-tracks"
    body: str = "classic_bipedal"
    teacher: str = "alp-gmm"
    student: str = "rsl-ppo"
    preset: str = "fast"
    steps: int = 2_000_000  # the quickstart: about 3 min on 2 cores (docs/benchmarks.md)
    n_envs: int | None = None  # None: the student's default (`effective_n_envs`)
    seed: int = 0
    out: str | None = None
    expert_knowledge: str = "high"
    shuffle_dimensions: bool = False
    scale_reward: bool = False
    # Robust PLR / ACCEL: the student does not learn on new or edited levels ("auto": whenever
    # the teacher marks such levels and the student can leave them out)
    exclude_exploratory: Literal["auto"] | bool = "auto"
    reset_student_every: int = 0
    bounds: dict[str, list[float]] = field(default_factory=dict)
    teacher_params: dict[str, Any] = field(default_factory=dict)
    student_params: dict[str, Any] = field(default_factory=dict)
    buffer_size: int | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    eval_every: int | None = None
    eval_envs: int | None = None
    # evaluations played side by side in one pass (torch-native students): None = 1 on the CPU
    # batched env, all of a default run's on the many-world simulation (`effective_eval_together`)
    eval_together: int | None = None
    eval_stochastic: bool = False
    test_set: str | None = None
    nb_test_episodes: int = 25
    checkpoint_every: int | None = None
    periodical_samples_every: int | None = None
    save_replay_buffer: bool = True
    vec_env: str = "auto"
    envs_per_worker: int | None = None
    start_method: str = "forkserver"
    torch_threads: int = 1
    progress_bar: bool = True
    tensorboard: bool = True  # TensorBoard event files under RUN/tb (the CSVs are always written)
    device: str = "cpu"
    verbose: int = 1

    def __post_init__(self):
        for name in _COUNTS:  # accept 2e6 for 2000000 from Python callers and YAML files
            value = getattr(self, name)
            if value is not None:
                setattr(self, name, check.integer(name, value, allow_float=True))
        if isinstance(self.out, os.PathLike):
            self.out = os.fspath(self.out)

    # ------------------------------------------------------------------ derived values
    @property
    def effective_eval_every(self) -> int:
        """TeachMyAgent's 500k, scaled down to 5 evaluations for runs shorter than 2.5M steps.

        Never below 50k by default: one pass over a 100-task test set can cost up to 200k env
        steps, so runs shorter than 100k steps get only the final evaluation (the run says so).
        On the many-world simulation, 10 evaluations a run (at least every 500k steps): a pass
        plays up to 2,000 steps one after the other (13 s on an H200) while the worlds train
        millions of steps in that time, so 40 passes would take most of a 20M-step run.
        """
        if self.eval_every is not None:
            return int(self.eval_every)
        if uses_many_worlds(self):
            return int(max(TEACHMYAGENT_EVAL_EVERY, self.steps // MANY_WORLD_EVALUATIONS))
        return int(min(TEACHMYAGENT_EVAL_EVERY, max(MIN_DEFAULT_EVAL_EVERY, self.steps // 5)))

    @property
    def effective_checkpoint_every(self) -> int:
        return int(self.checkpoint_every or self.effective_eval_every)

    @property
    def effective_periodical_samples(self) -> int:
        if self.periodical_samples_every is not None:
            return int(self.periodical_samples_every)
        return int(min(TEACHMYAGENT_PERIODICAL_SAMPLES, max(1, self.steps // 10)))

    @property
    def effective_eval_together(self) -> int:
        """How many evaluation steps' policies wait to be played side by side in one pass.

        On the many-world simulation a pass costs up to 2,000 steps one after the other, whatever
        its worlds: the 10 evaluations of a default run cost one pass at its end (their results
        are written then); on the CPU batched env each evaluation runs when it falls due.
        """
        if self.eval_together is not None:
            return int(self.eval_together)
        return MANY_WORLD_EVALUATIONS if uses_many_worlds(self) else 1

    @property
    def effective_n_envs(self) -> int:
        """`n_envs`, or the student's default: 16 envs for an SB3 student, 64 worlds for a
        torch-native one on the CPU, 4,096 on the many-world simulation. `train()` records the
        number in the run's config, so a later change of default never changes a run."""
        from acl3d.training.students import is_torch_native

        if self.n_envs is not None:
            return int(self.n_envs)
        if uses_many_worlds(self):
            return DEFAULT_GPU_WORLDS
        return DEFAULT_CPU_WORLDS if is_torch_native(self.student) else DEFAULT_N_ENVS

    @property
    def effective_eval_envs(self) -> int:
        return int(self.eval_envs or self.effective_n_envs)

    @property
    def eval_seed(self) -> int:
        """The seed of every evaluation pass of this run (`acl3d evaluate` reuses it)."""
        return int(self.seed) + EVAL_SEED_OFFSET

    @classmethod
    def from_dict(cls, values: dict) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown config option(s) {unknown}; valid: {sorted(known)}")
        return cls(**values)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def recorded(cls, values, where: str) -> TrainConfig:
        """The config a run directory recorded, refused when a field is missing or a mapping is
        not one (a torn or cut config.yaml), instead of defaults standing in for the run's values;
        `out` may be missing (exported runs drop it)."""
        if not isinstance(values, dict):
            raise ValueError(f"{where}: its 'config' section is not a mapping")
        values = {**RECORDED_BEFORE_THEY_EXISTED, **values}
        missing = [
            f.name for f in dataclasses.fields(cls) if f.name not in values and f.name != "out"
        ]
        if missing:
            raise ValueError(
                f"{where} lacks config field(s) {missing[:6]}{' ...' if len(missing) > 6 else ''}"
                " (torn or edited?); valid: the config.yaml that acl3d train wrote (config.json "
                "holds a copy)"
            )
        for name in _MAPPINGS:
            if not isinstance(values[name], dict):
                raise ValueError(f"{where}: config {check.fail(name, values[name], 'a mapping')}")
        return cls.from_dict(values)


# Options added after runs were recorded without them, with the value those runs had.
RECORDED_BEFORE_THEY_EXISTED = {"eval_together": None}

# Options a resumed run may change (runtime settings, and `steps` to extend it). Not the vec env
# kind or envs per worker: an in-process batched env pulls each task at its reset, worker
# processes get theirs pushed one episode ahead, so the teacher sees a different order.
RESUME_MAY_CHANGE = (
    "steps", "progress_bar", "verbose", "start_method", "torch_threads", "eval_envs",
    "eval_together", "tensorboard",
)  # fmt: skip


def fixed_settings(config: TrainConfig) -> dict:
    """The settings a run keeps for life (what a checkpoint was trained with), in JSON form:
    every option but those a resume may change and `out` (a run directory may be moved), with
    the evaluation and snapshot schedule as the numbers the run uses."""
    values = config.to_dict()
    for name in (*RESUME_MAY_CHANGE, "out"):
        values.pop(name)
    values["eval_every"] = config.effective_eval_every
    values["checkpoint_every"] = config.effective_checkpoint_every
    values["periodical_samples_every"] = config.effective_periodical_samples
    return json.loads(json.dumps(values))


# ---------------------------------------------------------------------- validation
_COUNTS = (
    "steps", "n_envs", "nb_test_episodes", "torch_threads", "eval_envs", "eval_every",
    "eval_together", "checkpoint_every", "buffer_size", "reset_student_every", "periodical_samples_every", "seed",
    "envs_per_worker",
)  # fmt: skip
_REQUIRED_COUNTS = ("steps", "nb_test_episodes", "torch_threads", "seed")
_MAY_BE_ZERO = ("reset_student_every", "periodical_samples_every", "seed")
_FLAGS = (
    "shuffle_dimensions",
    "scale_reward",
    "eval_stochastic",
    "save_replay_buffer",
    "progress_bar",
    "tensorboard",
)
_TEXTS = ("env", "body", "teacher", "student", "preset", "device")
_MAPPINGS = ("bounds", "teacher_params", "student_params", "env_kwargs")


def validate(config: TrainConfig, *, on_this_machine: bool = True) -> None:
    """Cheap checks of names, numbers and flags (everything that needs no environment).

    `on_this_machine=False` (a campaign submitted to a cluster) leaves out the bounds relative to
    this machine (its CPU cores, its devices): the node that trains the run checks those.
    """
    from acl3d.teachers import teacher_class
    from acl3d.training import students
    from acl3d.training.workers import check_vec_env

    for name in _TEXTS:
        value = getattr(config, name)
        if not isinstance(value, str) or not value:
            raise check.fail(name, value, "a non-empty string")
    teacher_class(config.teacher)  # an unknown name raises, listing the valid ones
    students.check_student(config.student, config.preset)
    check.choice("expert_knowledge", config.expert_knowledge, EXPERT_KNOWLEDGE)
    check_vec_env(config.vec_env, config.start_method)
    for name in _COUNTS:
        value = getattr(config, name)
        if value is not None or name in _REQUIRED_COUNTS:
            check.count(name, value, minimum=0 if name in _MAY_BE_ZERO else 1)
    _check_machine_bounds(config, on_this_machine)
    for name in _FLAGS:
        check.flag(name, getattr(config, name))
    check.integer("verbose", config.verbose, 0, 2)
    for name in _MAPPINGS:
        value = getattr(config, name)
        if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
            raise check.fail(name, value, "a mapping of names to values")
    for name, pair in config.bounds.items():
        check.real_array(f"bounds[{name!r}]", pair, shape=(2,))
    for name in ("out", "test_set"):
        if getattr(config, name) is not None:
            check.path(name, getattr(config, name))
    n_envs = config.effective_n_envs
    if config.envs_per_worker is not None and config.envs_per_worker > n_envs:
        raise check.fail(
            "envs_per_worker", config.envs_per_worker, f"None or an integer in [1, {n_envs}]"
        )
    if config.reset_student_every and config.reset_student_every >= config.steps:
        raise ValueError(
            f"reset_student_every ({config.reset_student_every}) must be < steps ({config.steps}), "
            "otherwise the student is never reset"
        )
    if config.eval_together not in (None, 1) and not students.is_torch_native(config.student):
        raise check.fail(
            "eval_together", config.eval_together, "None or 1 with an SB3 student (its "
            "evaluations run when they fall due); torch-native students: [1, 64]",
        )  # fmt: skip
    if config.vec_env == "warp" and not students.is_torch_native(config.student):
        raise check.fail(
            "vec_env", config.vec_env, "auto, batched, dummy or subproc with an SB3 student "
            "(warp, the many-world simulation, takes torch-native students: rsl-ppo)",
        )  # fmt: skip
    excludes_exploratory(config)


def cpu_cores() -> int:
    return os.cpu_count() or 1


def _check_machine_bounds(config: TrainConfig, on_this_machine: bool = True) -> None:
    """Upper bounds on counts that cost memory, processes or threads (the lower ones are above);
    those relative to this machine's cores and devices only `on_this_machine`."""
    from acl3d.devices import check_device
    from acl3d.envs.batched import MAX_ENVS
    from acl3d.sim.worlds import MAX_WORLDS

    check.integer(
        "n_envs", config.effective_n_envs, 1, MAX_WORLDS if uses_many_worlds(config) else MAX_ENVS
    )
    if config.eval_envs is not None:
        check.integer("eval_envs", config.eval_envs, 1, MAX_ENVS)
    if config.eval_together is not None:
        check.integer("eval_together", config.eval_together, 1, MAX_EVAL_TOGETHER)
    check.integer("nb_test_episodes", config.nb_test_episodes, 1, MAX_TEST_EPISODES)
    check.integer("seed", config.seed, 0, MAX_SEED)
    if not on_this_machine:
        return
    cores = cpu_cores()
    check.integer("torch_threads", config.torch_threads, 1, cores)
    most = max(MIN_WORKER_PROCESSES, 4 * cores)
    for name, n_envs in (
        ("n_envs", config.effective_n_envs),
        ("eval_envs", config.effective_eval_envs),
    ):
        workers = worker_processes(config, n_envs)
        if workers > most:
            raise check.fail(
                name,
                n_envs,
                f"at most {most} worker processes on this machine ({cores} CPU cores); "
                f"vec_env={config.vec_env!r} with envs_per_worker={config.envs_per_worker} "
                f"starts {workers} (use vec_env batched or a larger envs_per_worker)",
            )
    check_device(config.device)


def uses_many_worlds(config: TrainConfig) -> bool:
    """Whether the run trains on the many-world simulation (MuJoCo Warp): a torch-native student
    with vec_env warp, or auto on a GPU."""
    from acl3d.training.students import is_torch_native

    auto_gpu = config.vec_env == "auto" and str(config.device).startswith("cuda")
    return is_torch_native(config.student) and (config.vec_env == "warp" or auto_gpu)


def worker_processes(config: TrainConfig, n_envs: int) -> int:
    """How many worker processes `n_envs` envs of this config start (0: all in this process)."""
    from acl3d.training.workers import is_batchable

    if config.vec_env == "warp":  # one process: the many-world simulation
        return 0
    batched = config.vec_env == "batched" or (config.vec_env == "auto" and is_batchable(config.env))
    if batched:
        per_worker = config.envs_per_worker
        return 0 if per_worker is None or per_worker >= n_envs else -(-n_envs // per_worker)
    if config.vec_env == "dummy" or (config.vec_env == "auto" and n_envs == 1):
        return 0
    return n_envs


def excludes_exploratory(config: TrainConfig) -> bool:
    """Whether the run leaves the transitions of exploratory episodes (Robust PLR / ACCEL's new
    and edited levels) out of the student's updates; `exclude_exploratory=True` with a teacher
    that marks no level or a student that cannot exclude them is refused."""
    from acl3d.teachers import registered, teacher_class

    value = config.exclude_exploratory
    if not (isinstance(value, bool) or (isinstance(value, str) and value == "auto")):
        raise check.fail("exclude_exploratory", value, '"auto", True or False')
    marks = teacher_class(config.teacher).marks_exploratory
    if value is True and not marks:
        marking = [name for name in registered() if teacher_class(name).marks_exploratory]
        raise ValueError(
            f"exclude_exploratory=True: teacher {config.teacher!r} marks no exploratory levels; "
            f"valid with the teachers {', '.join(marking)}"
        )
    # SAC's memory-saving buffer takes each next observation from the next slot: no exclusions
    memory_saving = config.student_params.get("optimize_memory_usage")
    able = config.student in ("sac", "ppo", "rsl-ppo") and not memory_saving
    if value is True and not able:
        raise ValueError(
            f"exclude_exploratory=True: not possible with student {config.student!r}"
            + (" and optimize_memory_usage=True" if memory_saving else "")
            + "; valid: the sac, ppo or rsl-ppo student, with optimize_memory_usage=False"
        )
    if value == "auto":
        return marks and able
    return value
