"""Variants of the classic biped: small_bipedal (half-length legs) and amphibious_bipedal.

The amphibian has the classic geometry with water-relative densities (hull 1.25, legs 0.25 of
water's 1.0: it floats with its head up) and never dies from a contact; it reuses the classic
template and only changes masses and colours, so the two can never drift apart geometrically.
"""

from __future__ import annotations

import mujoco

from acl3d.bodies.classic_bipedal import ClassicBipedal

SMALL_LEG_LENGTH = 17 / 30
WATER_DENSITY = 1.0
HULL_AREA = 1.084  # m^2, the 5-gon hull of the classic biped
LIGHT_LIMB_ARMATURE = 0.1  # as in the templates of the other light-limbed bodies
UPPER_AREA, LOWER_AREA = (8 / 30) * (34 / 30), (6.4 / 30) * (34 / 30)


class SmallBipedal(ClassicBipedal):
    name = "small_bipedal"
    template = "bodies/small_bipedal.xml"
    spawn_height = 0.1 + 2 * SMALL_LEG_LENGTH + 0.02


class AmphibiousBipedal(ClassicBipedal):
    name = "amphibious_bipedal"
    kind = "amphibian"
    template = "bodies/classic_bipedal.xml"
    critical_geoms = ()  # the original amphibian's hull contact is never fatal

    def template_spec(self) -> mujoco.MjSpec:
        """The classic template with amphibious masses (area x relative density) and colours."""
        spec = super().template_spec()
        spec.modelname = "amphibious_bipedal"
        spec.geom("hull").mass = HULL_AREA * 1.25 * WATER_DENSITY
        spec.geom("hull").rgba = [0.44, 0.81, 0.14, 1.0]
        for side in ("left", "right"):
            for joint in ("hip", "knee"):  # legs 4x lighter: the light-limb armature
                spec.joint(f"{side}_{joint}").armature = LIGHT_LIMB_ARMATURE
            upper, lower = spec.geom(f"{side}_upper"), spec.geom(f"{side}_lower")
            upper.mass = UPPER_AREA * 0.25 * WATER_DENSITY
            lower.mass = LOWER_AREA * 0.25 * WATER_DENSITY
            upper.rgba = [0.36, 0.66, 0.11, 1.0]
            lower.rgba = [1.0, 0.25, 0.04, 1.0]
        return spec
