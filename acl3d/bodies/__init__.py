"""Embodiments: `make_body(name, planar=..., **options)`; `BODIES` lists the names.

Every TeachMyAgent body (walkers, climbers, the fish swimmer, the amphibian) plus dm_control's
locomotion walkers under a "dmc:" prefix (dm_control is imported only when one is built).
"""

from __future__ import annotations

import importlib
import inspect

from acl3d.bodies.base import Body, BoundBody, GraspSensor, Motor

# name -> "module:Class", in TeachMyAgent's order: walkers, climbers, swimmer, amphibian
_REGISTRY: dict[str, str] = {
    "classic_bipedal": "acl3d.bodies.classic_bipedal:ClassicBipedal",
    "small_bipedal": "acl3d.bodies.bipeds:SmallBipedal",
    "big_quadru": "acl3d.bodies.quadruped:BigQuadru",
    "spider": "acl3d.bodies.spider:Spider",
    "millipede": "acl3d.bodies.millipede:Millipede",
    "profile_chimpanzee": "acl3d.bodies.chimpanzee:ProfileChimpanzee",
    "wheel": "acl3d.bodies.wheel:Wheel",
    "climbing_profile_chimpanzee": "acl3d.bodies.chimpanzee:ClimbingProfileChimpanzee",
    "climbing_chest_profile_chimpanzee": "acl3d.bodies.chimpanzee:ClimbingChestProfileChimpanzee",
    "fish": "acl3d.bodies.fish:Fish",
    "amphibious_bipedal": "acl3d.bodies.bipeds:AmphibiousBipedal",
    "dmc:ant": "acl3d.bodies.dmc:Ant",
    "dmc:cmu_humanoid": "acl3d.bodies.dmc:CMUHumanoid",
}
# TeachMyAgent names of older variants that map onto ours (the "old" ones differ only by the
# spawn mis-placement bug and, for the quadruped, leg anchors at -1.2/+0.85 of the half hull)
ALIASES: dict[str, str] = {
    "old_classic_bipedal": "classic_bipedal",
    "old_big_quadru": "big_quadru",
}

BODIES: tuple[str, ...] = tuple(_REGISTRY)


def body_class(name: str) -> type[Body]:
    if not isinstance(name, str) or ALIASES.get(name, name) not in _REGISTRY:
        raise ValueError(f"unknown body {name!r}; valid bodies: {', '.join(BODIES)}")
    module, cls = _REGISTRY[ALIASES.get(name, name)].split(":")
    return getattr(importlib.import_module(module), cls)


def make_body(name: str, planar: bool | None = None, **options) -> Body:
    """Build a body description; unknown options raise with the valid ones listed."""
    cls = body_class(name)
    valid = [p for p in inspect.signature(cls.__init__).parameters if p not in ("self", "planar")]
    unknown = [k for k in options if k not in valid]
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for body {name!r}; valid: {valid or 'none'}")
    return cls(planar=planar, **options)


__all__ = [
    "ALIASES",
    "BODIES",
    "Body",
    "BoundBody",
    "GraspSensor",
    "Motor",
    "body_class",
    "make_body",
]
