"""TeachMyAgent's fish: the swimmer (head, 3 tail segments, 1 fin; density 0.99 of water's 1.0).

On Stump Tracks it flops on the ground like the original; water comes with Parkour. No part is
critical, every joint reports its part's contact, no spawn push, spawned 1 m higher than its
centre height, and no head-angle term in the reward.
"""

from __future__ import annotations

from acl3d.bodies.base import Body, Motor

DENSITY = 0.99  # relative to water (1.0): the fish sinks very slowly
CENTRE_HEIGHT = 9 / 30  # the original's AGENT_CENTER_HEIGHT
DROP = 1.0  # the original spawns the fish 1 m higher than other bodies


class Fish(Body):
    name = "fish"
    kind = "swimmer"
    template = "bodies/fish.xml"
    root = "head"
    motors = tuple(Motor(j, speed=6.0, contact_geom=j) for j in ("tail1", "tail2", "tail3", "fin"))
    torque = 80.0
    critical_geoms = ()
    head_angle_reward = False
    planar_default = False
    spawn_height = CENTRE_HEIGHT + DROP
    length = 35 / 30 + 40 / 30  # head + tail
    initial_push = False
