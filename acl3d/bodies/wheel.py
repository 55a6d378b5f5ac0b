"""TeachMyAgent's wheel: a cube with a two-segment leg on each of four faces (torque 500).

It rolls by pushing with the legs; the cube's contact ends the episode on Stump Tracks (as every
walker's hull there), and the reward has no head-angle term (it is meant to turn over).
"""

from __future__ import annotations

from acl3d.bodies.base import Body, Motor

CUBE = 20 / 30
LEG_LENGTH = 10 / 30


class Wheel(Body):
    name = "wheel"
    template = "bodies/wheel.xml"
    root = "main_body"
    motors = tuple(
        m
        for leg in ("bottom", "top", "left", "right")
        for m in (
            Motor(f"{leg}_hip", speed=4.0),
            Motor(f"{leg}_knee", speed=6.0, angle_correction=1.0, contact_geom=f"{leg}_lower"),
        )
    )
    torque = 500.0
    penalty_divisor = 2.0  # four legs = two pairs
    critical_geoms = ("main_body",)
    head_angle_reward = False
    spawn_height = CUBE / 2 + 2 * LEG_LENGTH + 0.02
    length = CUBE + 4 * LEG_LENGTH
