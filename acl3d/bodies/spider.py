"""TeachMyAgent's spider: a cube trunk with `nb_pairs_of_legs` pairs of 3-segment legs (torque 100).

Generated with MjSpec: each pair is a back leg and its mirror image, a front leg, attached to the
trunk's lower back and front edges (both at the same two corners in the 2D original, where the
pairs overlap; here each pair gets its own y position, spread over the trunk's depth). Motor order
follows the original: pair by pair, back leg then front leg, each hip, knee, ankle.
"""

from __future__ import annotations

import mujoco
import numpy as np

from acl3d import validation
from acl3d.assets import mjcf_path
from acl3d.bodies.base import Body, Motor

HALF_WIDTH = 10 / 30  # trunk half-size
LEG_DOWN = 4 / 30  # hips below the trunk centre
FOOT_DROP = 0.692  # lowest foot point below the trunk centre at rest (0.25/0.7/0.9 pi segments)
PAIR_SPREAD = 0.25  # outermost pairs' |y|, metres
MAX_PAIRS = 8
SIDES = (("back", -1.0), ("front", 1.0))  # name, x side of the trunk


class Spider(Body):
    name = "spider"
    template = "bodies/spider.xml"
    leg_template = "bodies/spider_leg.xml"
    root = "main_body"
    torque = 100.0
    critical_geoms = ("main_body",)
    planar_default = False
    spawn_height = FOOT_DROP + 0.02
    length = 2 * HALF_WIDTH + 4 * 20 / 30  # trunk + spread legs, as the original's AGENT_WIDTH

    def __init__(
        self,
        planar: bool | None = None,
        motors_torque: float | None = None,
        nb_pairs_of_legs: int = 2,
    ):
        super().__init__(planar=planar, motors_torque=motors_torque)
        self.nb_pairs_of_legs = validation.integer(
            "nb_pairs_of_legs", nb_pairs_of_legs, 1, MAX_PAIRS
        )
        self.penalty_divisor = float(self.nb_pairs_of_legs)
        self.motors = tuple(
            Motor(f"{leg}_{joint}", speed=speed, contact_geom=geom and f"{leg}_{geom}")
            for leg in self.leg_names()
            for joint, speed, geom in (
                ("hip", 4.0, None),
                ("knee", 4.0, None),
                ("ankle", 6.0, "lower"),
            )
        )

    def leg_names(self) -> list[str]:
        return [f"pair{k}_{side}" for k in range(self.nb_pairs_of_legs) for side, _ in SIDES]

    def pair_y(self) -> np.ndarray:
        n = self.nb_pairs_of_legs
        return np.linspace(PAIR_SPREAD, -PAIR_SPREAD, n) if n > 1 else np.zeros(1)

    def template_spec(self) -> mujoco.MjSpec:
        spec = super().template_spec()
        trunk = spec.body(self.root)
        for k, y in enumerate(self.pair_y()):
            for side, x in SIDES:
                leg = mujoco.MjSpec.from_file(str(mjcf_path(self.leg_template)))
                if x > 0:  # a front leg is the back leg mirrored: rotations about -y negated
                    for part in ("upper", "middle", "lower"):
                        body = leg.body(part)
                        body.quat = body.quat * np.array([1.0, -1.0, -1.0, -1.0])
                frame = trunk.add_frame(pos=[x * HALF_WIDTH, y, -LEG_DOWN])
                spec.attach(leg, prefix=f"pair{k}_{side}_", frame=frame)
        return spec
