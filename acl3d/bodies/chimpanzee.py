"""TeachMyAgent's profile chimpanzees: the walker (arms down, 3-part hands) and the two climbers.

All three share the head + trunk + limbs geometry (px / 30 m), torque 100, the torque penalty
divided by 5 (legs + arms + hands) and no head-angle term in the reward. Climbers carry one grasp
sensor per hand; their action vector is the motors followed by one grasp entry per hand.
"""

from __future__ import annotations

import mujoco

from acl3d.bodies.base import Body, GraspSensor, Motor

LIMB = 28 / 30  # upper and lower limb length, metres
LEG_DOWN = 12 / 30  # hip below the trunk centre
HEAD_ABOVE_TRUNK = 0.2 + 10 / 30 + 22.5 / 30  # head centre above the trunk centre
TRUNK_BOTTOM = 20 / 30  # trunk's lowest point below its centre
CLEARANCE = 0.02
SIDES = ("left", "right")


def _leg_motors() -> tuple[Motor, ...]:
    return tuple(
        m
        for s in SIDES
        for m in (
            Motor(f"{s}_hip", speed=4.0),
            Motor(f"{s}_knee", speed=6.0, angle_correction=1.0, contact_geom=f"{s}_lower_leg"),
        )
    )


class ProfileChimpanzee(Body):
    """Walker: legs and hanging arms; head and trunk contacts end the episode."""

    name = "profile_chimpanzee"
    template = "bodies/profile_chimpanzee.xml"
    root = "head"
    motors = _leg_motors() + tuple(
        m
        for s in SIDES
        for m in (
            Motor(f"{s}_shoulder", speed=4.0),
            Motor(f"{s}_elbow", speed=4.0),
            *(Motor(f"{s}_hand{k}", speed=8.0, contact_geom=f"{s}_hand{k}") for k in (1, 2, 3)),
        )
    )
    torque = 100.0
    penalty_divisor = 5.0
    critical_geoms = ("head", "trunk")
    head_angle_reward = False
    spawn_height = HEAD_ABOVE_TRUNK + LEG_DOWN + 2 * LIMB + CLEARANCE
    length = 24 / 30


class ClimbingProfileChimpanzee(Body):
    """Climber: arms up, one-part hands with grasp sensors; head, trunk and lower legs are critical."""

    name = "climbing_profile_chimpanzee"
    kind = "climber"
    template = "bodies/climbing_profile_chimpanzee.xml"
    root = "head"
    arm_motors = tuple(
        m
        for s in SIDES
        for m in (
            Motor(f"{s}_shoulder", speed=4.0),
            Motor(f"{s}_elbow", speed=4.0),
            Motor(f"{s}_hand", speed=8.0, contact_geom=f"{s}_hand"),
        )
    )
    motors = _leg_motors() + arm_motors
    torque = 100.0
    penalty_divisor = 5.0
    critical_geoms = ("head", "trunk", "left_lower_leg", "right_lower_leg")
    head_angle_reward = False
    spawn_height = HEAD_ABOVE_TRUNK + LEG_DOWN + 2 * LIMB + CLEARANCE
    length = 24 / 30
    grasp_sensors = tuple(GraspSensor(f"{s}_hand_sensor", f"{s}_hand") for s in SIDES)


class ClimbingChestProfileChimpanzee(ClimbingProfileChimpanzee):
    """The climber without legs (TeachMyAgent's climbing_chest_profile_chimpanzee)."""

    name = "climbing_chest_profile_chimpanzee"
    motors = ClimbingProfileChimpanzee.arm_motors
    critical_geoms = ("head", "trunk")
    spawn_height = HEAD_ABOVE_TRUNK + TRUNK_BOTTOM + CLEARANCE

    def template_spec(self) -> mujoco.MjSpec:
        """The climber's template with both legs (bodies and actuators) removed."""
        spec = super().template_spec()
        for side in SIDES:
            for joint in ("hip", "knee"):
                spec.delete(spec.actuator(f"{side}_{joint}"))
            spec.delete(spec.body(f"{side}_upper_leg"))
        return spec
