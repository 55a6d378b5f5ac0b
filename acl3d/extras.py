"""Optional dependencies: which `pip install "acl3d[EXTRA]"` brings which package.

The core install (environments, the numpy teachers, offscreen rendering) needs only mujoco,
gymnasium, numpy, scipy and pyyaml. Everything else is imported where it is used, inside
`optional_dependency(...)`, so a missing package fails with the command that installs it
instead of a bare `ModuleNotFoundError`.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

# importable name -> (distribution name, extra that installs it)
PACKAGES: dict[str, tuple[str, str]] = {
    "torch": ("torch", "train"),
    "stable_baselines3": ("stable-baselines3", "train"),
    "tensorboard": ("tensorboard", "train"),
    "matplotlib": ("matplotlib", "train"),
    "rich": ("rich", "train"),
    "imageio": ("imageio", "video"),
    "imageio_ffmpeg": ("imageio-ffmpeg", "video"),
    "PIL": ("pillow", "video"),
    "ray": ("ray", "campaign"),
    "rsl_rl": ("rsl-rl-lib", "train"),
    "tensordict": ("tensordict", "train"),
    "dm_control": ("dm-control", "dmc"),
    "sklearn": ("scikit-learn", "sklearn"),
    "syllabus": ("syllabus-rl", "syllabus"),
    "warp": ("warp-lang", "gpu"),
    "mujoco_warp": ("mujoco-warp", "gpu"),
}


class MissingExtraError(ModuleNotFoundError):
    """An optional package is missing; the message names the extra that installs it."""


def install_hint(module: str, extra: str | None = None) -> str:
    """`pip install "acl3d[EXTRA]"` for an importable name listed in PACKAGES (or `extra`)."""
    return f'pip install "acl3d[{extra or PACKAGES[module.split(".")[0]][1]}]"'


@contextmanager
def optional_dependency(purpose: str, extra: str | None = None) -> Iterator[None]:
    """Turn the import error of a missing optional package into one that says what to install:
    the extra holding that package, or `extra` when the purpose needs all of a larger one (a
    campaign needs [campaign] whichever of its packages is found missing first).

    Errors of other modules (a missing core package, a bug) pass through unchanged.
    """
    try:
        yield
    except MissingExtraError:
        raise
    except ModuleNotFoundError as exc:
        top = (exc.name or "").split(".")[0]
        if top not in PACKAGES:
            raise
        package, _ = PACKAGES[top]
        raise MissingExtraError(
            f"{purpose} needs the optional package {package!r}, which is not installed: "
            f"{install_hint(top, extra)}",
            name=exc.name,
        ) from exc
