"""What a run's student will run, derived from its `TrainConfig`: its hyper-parameters (preset,
then the run's overrides) and the steps it trains in (whole collections)."""

from __future__ import annotations

from acl3d.training.config import TrainConfig


def student_params(config: TrainConfig) -> dict:
    """The SB3 hyperparameters of the run: preset, then `student_params`, then `buffer_size`."""
    from acl3d.training import students

    overrides = dict(config.student_params)
    if config.buffer_size is not None:
        if config.student != "sac":
            raise ValueError(
                f"buffer_size applies to the sac student only, not {config.student!r} "
                "(other algorithms: student_params={'buffer_size': ...})"
            )
        overrides["buffer_size"] = config.buffer_size
    return students.hyperparameters(
        config.student, config.preset, config.effective_n_envs, overrides
    )


def steps_per_collection(student: str, params: dict, n_envs: int) -> int:
    """Env steps SB3 collects between two checks of its step budget (`students.collection_steps`)."""
    from acl3d.training import students

    return students.collection_steps(student, params, n_envs)


def round_steps(steps: int, unit: int) -> int:
    """`steps` rounded up to a whole number of collections (what SB3 will actually run)."""
    return -(-int(steps) // unit) * unit
