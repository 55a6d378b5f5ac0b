from pathlib import Path

import pytest
from run_safety_support import tiny_run, tiny_run_copy  # noqa: F401  (the run-safety fixtures)

import acl3d  # (picks the headless GL backend and registers the environments)


@pytest.fixture(scope="session")
def checkout() -> Path:
    """The checkout whose acl3d these tests import. Run `python -m acl3d` subprocesses in it:
    a subprocess puts its working directory before PYTHONPATH on sys.path, so with `PYTHONPATH=
    OTHER pytest` the tests would import OTHER and their subprocesses this directory's acl3d, and
    a run compared across the two processes (killed, then resumed here) would mix two codes."""
    return Path(acl3d.__file__).resolve().parents[1]
