"""`train(config)`: a Stable-Baselines3 student learning on a teacher's curriculum, resumable.

The run is checked completely (names, bounds, teacher/profile combination, student settings,
the resume point and step budget) before any worker starts or any file of the run directory is
touched, so a bad command fails in a second with the reason and changes nothing. The pieces:
`config` (options and validation), `session` (envs, student, controller, checkpoints),
`callbacks` (logging, evaluation, checkpoints, student resets).
"""

from __future__ import annotations

import dataclasses
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import torch
from stable_baselines3.common.callbacks import BaseCallback, CallbackList

from acl3d import provenance
from acl3d import validation as check
from acl3d.atomic_files import is_disk_full
from acl3d.run_format.tables import read_csv, truncate_csv
from acl3d.teachers import test_sets
from acl3d.training import students
from acl3d.training.callbacks import run_callbacks
from acl3d.training.config import RESUME_MAY_CHANGE, TrainConfig, validate
from acl3d.training.run_dir import RunDir, read_state
from acl3d.training.session import Session, verify_checkpoint
from acl3d.training.sigterm import sigterm_interrupts
from acl3d.training.student_settings import round_steps, steps_per_collection, student_params


@dataclass
class TrainResult:
    run_dir: Path
    steps: int
    final_eval: dict[str, float] | None


def train(
    config: TrainConfig | dict | None = None,
    *,
    resume=None,
    overwrite: bool = False,
    callbacks: list[BaseCallback] | None = None,
    **overrides,
) -> TrainResult:
    """Train a student on a teacher's curriculum; or continue `resume` (a run directory).

    `overrides` set config fields (`train(teacher="alp-gmm", steps=10_000, out="runs/x")`). On
    resume the saved config is used; only `steps` (to extend a run) and runtime options
    (`RESUME_MAY_CHANGE`) may be changed, and the run continues bit for bit from its newest
    checkpoint whose files all read back (else the previous one the run keeps). `overwrite`
    starts a new run in place of the one in `out` (deleting it). `callbacks` are your own SB3
    callbacks: they run after the run's own (logging, evaluation, checkpoints) at every SB3
    event, see `self.model`, and may stop training early by returning False from `_on_step`
    (the run then ends with a final evaluation and checkpoint).

    Nothing is written before the whole run is checked and built (options, test set, envs,
    student, the checkpoint to resume): a rejected call leaves the run directory as it was. A
    run directory is used by one process at a time (`RunInUseError` otherwise).

    SB3 collects whole rollouts (PPO: n_steps x n_envs; SAC: train_freq x n_envs), so `steps` is
    rounded up to a whole number of them; the run prints the rounding and records the steps it
    trains as `resolved.steps` in config.yaml.
    """
    user_callbacks = _check_callbacks(callbacks)
    check.flag("overwrite", overwrite)
    if resume is None:
        if isinstance(config, TrainConfig):
            config = dataclasses.replace(config, **overrides)
        else:
            config = TrainConfig.from_dict(dict(config or {}, **overrides))
        if isinstance(config.student, type):  # an algorithm class: recorded as "module:Class"
            config = dataclasses.replace(config, student=students.spec(config.student))
        if not config.out:
            raise ValueError("out (the run directory) is required")
        validate(config)
        config = dataclasses.replace(config, n_envs=config.effective_n_envs)  # the run records it
        run = RunDir(config.out)
        run.check_new(overwrite)
        return _start(config, run, None, user_callbacks, overwrite)
    if overwrite:
        raise ValueError("overwrite=True starts a new run; it does not apply to resume")
    run = RunDir(resume)
    if not run.exists():
        raise ValueError(f"{str(run.path)!r} is not a run directory (no config.yaml)")
    run.lock()
    try:
        config = _resumed_config(run, dict(config or {}, **overrides))
        validate(config)
        resume_from = run.resume_point(lambda folder: verify_checkpoint(folder, config))
        return _start(config, run, resume_from, user_callbacks, overwrite)
    finally:
        run.unlock()


def _start(config, run, resume_from, user_callbacks, overwrite) -> TrainResult:
    start = 0 if resume_from is None else int(read_state(resume_from / "progress")["num_timesteps"])
    target, rounding = _target_steps(config, start, finished=run.status() == "finished")

    def checked(test_tasks) -> None:  # the run's checks passed: what matters once it starts
        if rounding is not None:
            _note(rounding)
        if resume_from is None:  # warnings: printed with --quiet too
            _announce_evaluations(config, target, test_tasks)

    if students.is_torch_native(config.student):  # its own loop on tensor worlds
        from acl3d.training.torch_student.launch import train_run

        if user_callbacks:
            raise ValueError(f"callbacks: SB3 callbacks do not apply to {config.student!r}")
        try:
            steps = train_run(config, run, resume_from, target, overwrite, checked)
        finally:
            run.unlock()
        return TrainResult(run.path, steps, _last_eval(run))
    session = Session(config, run, resume_from)  # builds the controller: fails before any worker
    checked(session.controller.test_tasks())
    sections = {
        "student_hyperparameters": session.params,
        "resolved": {
            "steps": target,
            "eval_every": config.effective_eval_every,
            "checkpoint_every": config.effective_checkpoint_every,
            "periodical_samples_every": config.effective_periodical_samples,
            "exclude_exploratory": session.exclude_exploratory,
            "nb_test_episodes": session.controller.nb_test_episodes,
        },
    }
    if session.controller.marks_exploratory and config.verbose:
        how = (
            "excluded from" if session.exclude_exploratory else "kept in (exclude_exploratory off)"
        )
        print(
            f"[acl3d] {config.teacher}: the episodes of exploratory (new or edited) levels are "
            f"{how} {config.student.upper()}'s updates",
            file=sys.stderr,
            flush=True,
        )
    torch.set_num_threads(config.torch_threads)
    try:
        return _run(session, target, user_callbacks, sections, overwrite)
    finally:
        run.unlock()


def _check_callbacks(callbacks) -> list[BaseCallback]:
    callbacks = list(callbacks or [])
    for cb in callbacks:
        if not isinstance(cb, BaseCallback):
            raise ValueError(
                f"callbacks: {cb!r} is not a stable_baselines3 BaseCallback; valid: a list of them"
            )
    return callbacks


def _resumed_config(run: RunDir, changes: dict) -> TrainConfig:
    """The saved config with the allowed changes; the evaluation and snapshot schedule stay
    those the run started with (their defaults would otherwise scale with the new steps)."""
    saved = TrainConfig.from_dict(run.read_config())
    changed = {k: v for k, v in changes.items() if v is not None}
    bad = sorted(
        k for k, v in changed.items() if k not in RESUME_MAY_CHANGE and getattr(saved, k, v) != v
    )
    if bad:
        raise ValueError(
            f"cannot change {bad} when resuming; only {sorted(RESUME_MAY_CHANGE)} may change"
        )
    config = dataclasses.replace(
        saved, **{k: v for k, v in changed.items() if k in RESUME_MAY_CHANGE}
    )
    resolved = run.read_section("resolved")
    return dataclasses.replace(
        config,
        eval_every=config.eval_every or resolved["eval_every"],
        checkpoint_every=config.checkpoint_every or resolved["checkpoint_every"],
        periodical_samples_every=config.periodical_samples_every
        if config.periodical_samples_every is not None
        else resolved["periodical_samples_every"],
    )


def _target_steps(config: TrainConfig, start: int, finished: bool) -> tuple[int, str | None]:
    """The step count the run trains to: `steps` rounded up to whole collections, and the note
    that says so when it differs (printed once the run's checks have passed). A finished run
    that already has `steps` is refused; an unfinished one (killed after its last checkpoint)
    only writes its final model."""
    unit = steps_per_collection(config.student, student_params(config), config.n_envs)
    target = start + round_steps(max(0, config.steps - start), unit)
    if start >= config.steps and finished:
        raise ValueError(
            f"steps={config.steps}: the run already has {start} steps; pass a larger steps "
            "value to extend it"
        )
    if target == config.steps or not config.verbose:
        return target, None
    what = (
        "rollouts" if students.is_on_policy(config.student) else "collections (train_freq x n_envs)"
    )
    return target, (
        f"steps={config.steps} is not a whole number of {config.student.upper()} {what} of "
        f"{unit} steps: training {target} steps"
    )


def _announce_evaluations(config: TrainConfig, target: int, test_tasks) -> None:
    """Say up front what the evaluations will be where the options alone do not tell: a default
    test set of another size than asked (a grid keeps floor(n^(1/d)) points per dimension), or a
    run too short for more than its final evaluation."""
    n = len(test_tasks)
    if not test_sets.generated(config.test_set) and n != config.nb_test_episodes:
        _note(
            f"test_set={config.test_set}: a file of {n} test tasks (nb_test_episodes="
            f"{config.nb_test_episodes} sizes a test set drawn at a size)"
        )
    if config.test_set is None and n != config.nb_test_episodes:
        varying = int(sum(len(set(column)) > 1 for column in zip(*test_tasks)))
        points = round(n ** (1 / max(varying, 1)))
        _note(
            f"nb_test_episodes={config.nb_test_episodes}: the default test set is a "
            f"{' x '.join([str(points)] * varying)} grid: {n} test tasks"
        )
    if target < 2 * config.effective_eval_every:
        _note(
            f"steps={target} < 2 x eval_every={config.effective_eval_every}: one evaluation, at "
            "the end of training; pass eval_every (--eval-every) for a learning curve"
        )


def _note(text: str) -> None:
    print(f"[acl3d] {text}", file=sys.stderr, flush=True)


def _run(session: Session, target: int, user_callbacks, sections: dict, overwrite: bool):
    config, run = session.config, session.run
    started = False
    # Batch schedulers stop jobs with SIGTERM: end like Ctrl-C, with the status written.
    with sigterm_interrupts():
        try:
            with session:
                session.build_student()  # the last check: from here on the run really starts
                _write_start(session, sections, overwrite)
                started = True
                model = session.model
                start = int(model.num_timesteps)
                if session.resume_from is not None:
                    for path in (run.evals_csv, run.evals_tasks_csv, run.episodes_csv):
                        truncate_csv(path, "step", start)
                if target > start:
                    model.learn(
                        total_timesteps=target - start,
                        callback=CallbackList([*run_callbacks(session, start), *user_callbacks]),
                        progress_bar=config.progress_bar,
                        reset_num_timesteps=session.resume_from is None,
                        tb_log_name="train",
                    )
                session.save_final_model()
                session.dump_teacher()
        except KeyboardInterrupt:
            if started:
                _best_effort(run.set_status, "interrupted", latest_checkpoint=_latest(run))
                _best_effort(provenance.close, run.path, "interrupted", int(model.num_timesteps))
            raise
        except BaseException as exc:
            if started:
                _record_crash(run, exc)
                _best_effort(provenance.close, run.path, "crashed", int(model.num_timesteps))
            raise
    run.set_status("finished", steps=int(model.num_timesteps))
    provenance.close(run.path, "finished", int(model.num_timesteps))
    return TrainResult(run.path, int(model.num_timesteps), _last_eval(run))


def _write_start(session: Session, sections: dict, overwrite: bool) -> None:
    """Write the run's config and `running` status (a new run's directory is made and locked
    here; a resumed one is locked already): temporary files of a killed writer go first."""
    run, config = session.run, session.config
    if session.resume_from is None:
        run.create(config.to_dict(), overwrite=overwrite, **sections)
    else:
        run.remove_temp_files()
        run.restart_from(session.resume_from)
        run.update_config(config.to_dict(), **sections)
    run.set_status("running", pid=os.getpid())
    event = "start" if session.resume_from is None else "resume"
    provenance.record(run.path, event, int(session.model.num_timesteps), config.device)


def _record_crash(run: RunDir, exc: BaseException) -> None:
    """`crashed` with the traceback; on a full disk a short status (the long one may not fit),
    and no error of this write hides the original one."""
    if is_disk_full(exc):
        _best_effort(
            run.set_status,
            "crashed",
            error="no space left on device",
            latest_checkpoint=_latest(run),
        )
    else:
        _best_effort(run.set_crashed, exc)


def _latest(run: RunDir) -> str | None:
    try:
        return run.latest_checkpoint_name()
    except OSError:
        return None


def _best_effort(write, *args, **kwargs) -> None:
    try:
        write(*args, **kwargs)
    except OSError:
        pass


def _last_eval(run: RunDir) -> dict[str, float] | None:
    cols = read_csv(run.evals_csv)
    if not cols or not cols["step"]:
        return None
    return {k: v[-1] for k, v in cols.items()}
