"""Curriculum teachers behind one interface: `make(name, task_space, seed=..., **params)`."""

from __future__ import annotations

import importlib
import inspect

from acl3d.extras import optional_dependency
from acl3d.teachers.base import Teacher, load_state, save_state

# name -> "module:Class"; modules are imported lazily so torch loads only for teachers that need it.
_REGISTRY: dict[str, str] = {
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

TEACHERS: tuple[str, ...] = tuple(_REGISTRY)


def teacher_class(name: str) -> type[Teacher]:
    if name not in _REGISTRY:
        raise ValueError(f"unknown teacher {name!r}; valid teachers: {', '.join(TEACHERS)}")
    module, cls = _REGISTRY[name].split(":")
    with optional_dependency(f"teacher {name!r}"):
        return getattr(importlib.import_module(module), cls)


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


__all__ = ["TEACHERS", "Teacher", "load_state", "make", "save_state", "teacher_class"]
