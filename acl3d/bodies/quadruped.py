"""TeachMyAgent's big_quadru: a long hull on two pairs of biped legs (torque 300, penalty / 2)."""

from __future__ import annotations

from acl3d.bodies.base import Body, Motor

LEG_LENGTH = 51 / 30


class BigQuadru(Body):
    name = "big_quadru"
    template = "bodies/big_quadru.xml"
    root = "hull"
    motors = tuple(
        m
        for leg in ("rear_left", "rear_right", "front_left", "front_right")
        for m in (
            Motor(f"{leg}_hip", speed=4.0),
            Motor(f"{leg}_knee", speed=6.0, angle_correction=1.0, contact_geom=f"{leg}_lower"),
        )
    )
    torque = 300.0
    penalty_divisor = 2.0  # two pairs of legs
    critical_geoms = ("hull",)
    planar_default = False
    spawn_height = 0.1 + 2 * LEG_LENGTH + 0.02
    length = 96 / 30
