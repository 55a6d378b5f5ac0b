"""TeachMyAgent's classic_bipedal: the benchmark walker (hull + two 2-segment legs, torque 80)."""

from acl3d.bodies.base import Body, Motor

LEG_LENGTH = 34 / 30  # metres per leg segment


class ClassicBipedal(Body):
    name = "classic_bipedal"
    template = "bodies/classic_bipedal.xml"
    root = "hull"
    motors = (
        Motor("left_hip", speed=4.0),
        Motor("left_knee", speed=6.0, angle_correction=1.0, contact_geom="left_lower"),
        Motor("right_hip", speed=4.0),
        Motor("right_knee", speed=6.0, angle_correction=1.0, contact_geom="right_lower"),
    )
    torque = 80.0
    critical_geoms = ("hull",)
    spawn_height = 0.1 + 2 * LEG_LENGTH + 0.02  # hip drop + two legs + clearance
    length = 64 / 30
