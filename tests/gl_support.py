"""Tests that need an OpenGL library skip, with the Debian package to install, where it is absent.

CI sets ACL3D_REQUIRE_GL=1 (see .ci/run), which turns those skips into failures: a CI machine
that lost its Mesa packages fails loudly instead of skipping the rendering tests silently.
"""

from __future__ import annotations

import os

import pytest

from acl3d.rendering import BACKEND_LIBRARIES, library_available

REQUIRE_VARIABLE = "ACL3D_REQUIRE_GL"


def missing(reason: str) -> None:
    """Skip with `reason` (the package to install), or fail under ACL3D_REQUIRE_GL=1."""
    if os.environ.get(REQUIRE_VARIABLE) == "1":
        pytest.fail(f"{reason} ({REQUIRE_VARIABLE}=1: rendering tests may not be skipped)")
    pytest.skip(reason)


def require_backend(backend: str) -> None:
    """Skip (or fail under ACL3D_REQUIRE_GL=1) unless `backend`'s library loads."""
    lib, packages = BACKEND_LIBRARIES[backend]
    if not library_available(backend):
        missing(f"MUJOCO_GL={backend} needs lib{lib}: apt-get install {packages}")


def require_offscreen_gl() -> None:
    """Skip (or fail) unless this process renders offscreen: the backend acl3d chose is present."""
    backend = os.environ.get("MUJOCO_GL")
    if backend in BACKEND_LIBRARIES:
        require_backend(backend)
    elif not os.environ.get("DISPLAY"):
        packages = " or ".join(p for _, p in BACKEND_LIBRARIES.values())
        missing(f"no display and no EGL/OSMesa library: apt-get install {packages}")


def require_program(program: str, package: str) -> None:
    """Skip (or fail) unless `program` is on PATH."""
    import shutil

    if shutil.which(program) is None:
        missing(f"{program} is missing: apt-get install {package}")


def run_checked(proc_args, **kwargs):
    """subprocess.run that fails with the child's stderr, so pytest shows why it failed."""
    import subprocess

    proc = subprocess.run(proc_args, capture_output=True, text=True, timeout=180, **kwargs)
    if proc.returncode != 0:
        pytest.fail(f"subprocess exited {proc.returncode}; its stderr:\n{proc.stderr}")
    return proc
