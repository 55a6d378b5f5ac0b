"""TeachMyAgent's millipede: `nb_of_bodies` cube segments in a row, each with one leg pair.

Generated with MjSpec from one segment template: the front segment is the head (the root: lidar
origin, reward x); each following segment hangs behind the previous one on a passive hinge
(+-0.05 pi). Motor order follows the original: from the rearmost segment to the head, each
left hip, left knee, right hip, right knee. As in the original, no contact is critical.
"""

from __future__ import annotations

import mujoco

from acl3d import validation
from acl3d.assets import mjcf_path
from acl3d.bodies.base import Body, Motor

SEGMENT = 20 / 30
LEG_DOWN = 3 / 30
LEG_LENGTH = 10 / 30
MAX_BODIES = 12


class Millipede(Body):
    name = "millipede"
    template = "bodies/millipede_segment.xml"
    torque = 200.0
    critical_geoms = ()
    planar_default = False
    spawn_height = LEG_DOWN + 2 * LEG_LENGTH + 0.02

    def __init__(
        self,
        planar: bool | None = None,
        motors_torque: float | None = None,
        nb_of_bodies: int = 4,
    ):
        super().__init__(planar=planar, motors_torque=motors_torque)
        n = validation.integer("nb_of_bodies", nb_of_bodies, 1, MAX_BODIES)
        self.nb_of_bodies = n
        self.penalty_divisor = float(n)  # one pair of legs per segment
        self.length = SEGMENT * n
        self.root = f"seg{n - 1}_segment"
        self.motors = tuple(
            m
            for j in range(n)
            for side in ("left", "right")
            for m in (
                Motor(f"seg{j}_{side}_hip", speed=4.0),
                Motor(
                    f"seg{j}_{side}_knee",
                    speed=6.0,
                    angle_correction=1.0,
                    contact_geom=f"seg{j}_{side}_lower",
                ),
            )
        )

    def template_spec(self) -> mujoco.MjSpec:
        """Segments seg{n-1} (head, no spine joint) to seg0 (rear), each hanging behind the last."""
        spec = mujoco.MjSpec()
        spec.modelname = "millipede"
        parent, pos = spec.worldbody, [0.0, 0.0, 0.0]
        for j in reversed(range(self.nb_of_bodies)):
            segment = mujoco.MjSpec.from_file(str(mjcf_path(self.template)))
            if parent is spec.worldbody:
                segment.delete(segment.joint("spine"))
            if j % 2:  # alternate shades so the segments read apart
                segment.geom("segment").rgba = [0.4, 0.32, 0.75, 1.0]
            spec.attach(segment, prefix=f"seg{j}_", frame=parent.add_frame(pos=pos))
            parent, pos = spec.body(f"seg{j}_segment"), [-SEGMENT, 0.0, 0.0]
        return spec
