"""Curriculum teachers behind one interface: `make(name, task_space, seed=..., **params)`.

A teacher of your own is one `Teacher` subclass and one `register(MyTeacher)`; after that it is
built by name like the shipped ones (`train(teacher=MyTeacher.name)`). A name of the form
"package.module:Class" is imported on first use, so `acl3d train --teacher mypkg.teachers:Mine`
works from the command line without registering anything.
"""

from __future__ import annotations

import difflib
import importlib
import inspect

from acl3d.extras import optional_dependency
from acl3d.teachers.base import RunFacts, Teacher
from acl3d.teachers.state_files import load_state, save_state

# name -> "module:Class" or a registered class; modules are imported lazily so torch loads only
# for teachers that need it.
_REGISTRY: dict[str, str | type[Teacher]] = {
    "random": "acl3d.teachers.random_teacher:RandomTeacher",
    "alp-gmm": "acl3d.teachers.alp_gmm:ALPGMM",
    "covar-gmm": "acl3d.teachers.covar_gmm:CovarGMM",
    "riac": "acl3d.teachers.riac:RIAC",
    "adr": "acl3d.teachers.adr:ADR",
    "self-paced": "acl3d.teachers.self_paced:SelfPaced",
    "goal-gan": "acl3d.teachers.goal_gan:GoalGAN",
    "setter-solver": "acl3d.teachers.setter_solver:SetterSolver",
    "oracle": "acl3d.teachers.oracle:Oracle",
    "lessons": "acl3d.teachers.lessons:Lessons",
    "robust-plr": "acl3d.teachers.plr:RobustPLR",
    "accel": "acl3d.teachers.plr:ACCEL",
    "terrain-levels": "acl3d.teachers.terrain_levels:TerrainLevels",
}

TEACHERS: tuple[str, ...] = tuple(_REGISTRY)  # the shipped teachers


def registered() -> tuple[str, ...]:
    """The names `make` knows: the shipped teachers, then those added with `register`."""
    return tuple(_REGISTRY)


def register(cls: type[Teacher]) -> type[Teacher]:
    """Make `cls` buildable by its `name` (usable as a class decorator)."""
    if not (isinstance(cls, type) and issubclass(cls, Teacher)) or inspect.isabstract(cls):
        raise ValueError(f"register({cls!r}): expected a concrete subclass of Teacher")
    name = cls.name
    if not isinstance(name, str) or not name or name == Teacher.name or ":" in name:
        raise ValueError(f"{cls.__name__}.name={name!r}; valid: a new non-empty name without ':'")
    if name in _REGISTRY and _REGISTRY[name] is not cls:
        raise ValueError(f"a teacher named {name!r} is already registered")
    _REGISTRY[name] = cls
    return cls


def teacher_class(name: str) -> type[Teacher]:
    """The class of a registered name, or of a "package.module:Class" path."""
    if not isinstance(name, str) or (name not in _REGISTRY and ":" not in name):
        close = difflib.get_close_matches(str(name), registered(), n=1)
        guess = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(
            f"unknown teacher {name!r}{guess}; valid teachers: {', '.join(registered())} "
            "or a 'package.module:Class' path"
        )
    entry = _REGISTRY.get(name, name)
    if isinstance(entry, type):
        return entry
    module, _, attr = entry.partition(":")
    if name in _REGISTRY:  # a shipped teacher: a missing extra says which to install
        with optional_dependency(f"teacher {name!r}"):
            return getattr(importlib.import_module(module), attr)
    try:
        cls = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"teacher {name!r}: cannot import it ({exc})") from None
    if not (isinstance(cls, type) and issubclass(cls, Teacher)):
        raise ValueError(f"teacher {name!r} is {cls!r}, not a subclass of Teacher")
    return cls


def make(name: str, task_space, seed: int | None = None, **params) -> Teacher:
    """Build a teacher by name; unknown names or parameters raise with the valid ones listed."""
    cls = teacher_class(name)
    sig = inspect.signature(cls.__init__)
    valid = [p for p in sig.parameters if p not in ("self", "task_space", "seed")]
    unknown = [p for p in params if p not in valid]
    if unknown:
        raise ValueError(
            f"unknown parameter(s) {unknown} for teacher {name!r}; valid: {', '.join(valid)}"
        )
    return cls(task_space, seed=seed, **params)


__all__ = [
    "TEACHERS",
    "RunFacts",
    "Teacher",
    "load_state",
    "make",
    "register",
    "registered",
    "save_state",
    "teacher_class",
]
