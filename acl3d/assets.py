"""Where the MJCF templates are: inside the installed wheel (acl3d/mjcf) or the source tree (mjcf/)."""

from __future__ import annotations

from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parent


def mjcf_dir() -> Path:
    for candidate in (_PACKAGE_DIR / "mjcf", _PACKAGE_DIR.parent / "mjcf"):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"MJCF templates not found next to {_PACKAGE_DIR}; reinstall acl3d")


def mjcf_path(relative: str) -> Path:
    """Path of a template, e.g. `mjcf_path("bodies/classic_bipedal.xml")`."""
    path = mjcf_dir() / relative
    if not path.is_file():
        raise FileNotFoundError(f"MJCF template {relative!r} not found in {mjcf_dir()}")
    return path
