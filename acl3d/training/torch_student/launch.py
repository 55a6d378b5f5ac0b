"""A torch-native run as its process sees it: every check before anything is written, the
resolved settings the run records, SIGTERM as an interruption, and the run's final status and
provenance (finished, interrupted or crashed, as for SB3 students). `TorchRun` trains."""

from __future__ import annotations

import torch

from acl3d import provenance
from acl3d.envs.batched import MAX_ENVS
from acl3d.training.config import TrainConfig
from acl3d.training.run_dir import RunDir
from acl3d.training.sigterm import sigterm_interrupts
from acl3d.training.torch_student.run import TorchRun


def train_run(
    config: TrainConfig, run: RunDir, resume_from, target: int, overwrite: bool, checked=None
) -> int:
    """Train `config`'s torch-native student to `target` steps in `run` (new or resumed); the
    run's status says finished, interrupted (Ctrl-C, SIGTERM) or crashed, as for SB3 students.
    `checked(test_tasks)`, if given, is called once the run's checks have passed."""
    torch_run = TorchRun(config, run, resume_from)  # every check before anything is written
    if checked is not None:
        checked(torch_run.controller.test_tasks())
    sections = {
        "student_hyperparameters": torch_run.params,
        "resolved": {
            "steps": target,
            "eval_every": config.effective_eval_every,
            "checkpoint_every": config.effective_checkpoint_every,
            "periodical_samples_every": config.effective_periodical_samples,
            "exclude_exploratory": torch_run.exclude_exploratory,
            "teacher_reserve": torch_run.curriculum.reserve,
            "nb_test_episodes": torch_run.controller.nb_test_episodes,
            "eval_worlds": min(
                len(torch_run.controller.test_tasks()), config.eval_envs or MAX_ENVS
            ),
        },
    }
    torch.set_num_threads(config.torch_threads)
    with sigterm_interrupts():
        try:
            steps = torch_run.train(target, sections, overwrite)
        except KeyboardInterrupt:
            if run.exists():
                run.set_status("interrupted", latest_checkpoint=run.latest_checkpoint_name())
            _close_provenance(torch_run, "interrupted")
            raise
        except BaseException as exc:
            if run.exists():
                run.set_crashed(exc)
            _close_provenance(torch_run, "crashed")
            raise
    run.set_status("finished", steps=steps, seconds_by_phase=torch_run.times.report())
    provenance.close(run.path, "finished", steps)
    return steps


def _close_provenance(torch_run: TorchRun, end: str) -> None:
    """End the segment this process recorded (none when it stopped before the run started); a
    failing write (a full disk) never hides the error that ended the run."""
    if torch_run.steps is None:
        return
    try:
        provenance.close(torch_run.run.path, end, torch_run.steps)
    except OSError:
        pass
