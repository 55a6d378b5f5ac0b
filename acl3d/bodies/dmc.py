"""dm_control locomotion walkers (Ant, CMU humanoid) as acl3d bodies, on any acl3d track.

The walker's MJCF comes from dm_control (`walker.mjcf_model`, exported to an XML string) into an
MjSpec and is adapted to acl3d's body conventions:
- its root gets acl3d's root joints (free by default, or planar), placed by the arena;
- every geom joins the body collision scheme (contype 0, conaffinity 1, group 1): walkers never
  self-collide, touch only the terrain, and the lidars never see them;
- its actuators are replaced by acl3d's velocity servos, one per actuated joint, named like the
  joint, so the track env drives them like every other body: target speed `speed * sign(a)`,
  torque capped at `max_torque_j * |a|`, where max_torque_j is the walker's own limit for that
  joint (dm_control's gear x ctrl limit, or its force range). The per-joint limit is the servo's
  gear and `Body.torque` is 1, so one torque cap per step serves joints of different strengths;
- its sensors are dropped (the tracks' rules compute the observation).
The observation is acl3d's: head (root) state, every actuated joint's angle and velocity (its
proprioception), foot contact flags, then the lidars.
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np

from acl3d.bodies.base import Body, Motor
from acl3d.extras import optional_dependency

SERVO_GAIN = 200.0  # joint-space servo damping, N.m per rad/s, as the other bodies' velocity servos
CLEARANCE = 0.02


def _ant():
    with optional_dependency("body 'dmc:ant'"):
        from dm_control.locomotion.walkers import ant

    return ant.Ant()


def _cmu_humanoid():
    with optional_dependency("body 'dmc:cmu_humanoid'"):
        from dm_control.locomotion.walkers import cmu_humanoid

    return cmu_humanoid.CMUHumanoidPositionControlledV2020()


@functools.cache
def walker_xml(builder) -> str:
    """The walker's MJCF, built once per process (dm_control's build takes ~0.1-0.3 s)."""
    return builder().mjcf_model.to_xml_string()


def _max_torque(actuator: mujoco.MjsActuator) -> float:
    """The largest joint torque the walker's own actuator can apply."""
    if actuator.forcelimited == mujoco.mjtLimited.mjLIMITED_TRUE or np.any(actuator.forcerange):
        return float(np.abs(actuator.forcerange).max() * abs(actuator.gear[0]))
    return float(np.abs(actuator.ctrlrange).max() * abs(actuator.gear[0]))


class DmcWalker(Body):
    """A dm_control walker adapted to acl3d; subclasses name the walker and its parts."""

    builder: staticmethod
    critical: tuple[str, ...] = ()
    feet: tuple[str, ...] = ()  # geoms whose contact is observed, after the joint they start with
    speeds: dict[str, float] = {}  # servo speed by joint-name fragment; default 4 rad/s
    torque = 1.0  # the per-joint limits are the servo gears (see module docstring)
    planar_default = False

    def __init__(self, planar: bool | None = None):
        super().__init__(planar=planar)
        spec = self._adapted_spec()
        self._joints = [a.target for a in spec.actuators]
        self.critical_geoms = self.critical
        self.motors = tuple(
            Motor(j, speed=self._speed(j), contact_geom=self._foot(j)) for j in self._joints
        )
        low, high = self._extent(spec)
        self.spawn_height = -low[2] + CLEARANCE
        self.length = float(high[0] - low[0])

    def _speed(self, joint: str) -> float:
        return next((s for k, s in self.speeds.items() if k in joint), 4.0)

    def _foot(self, joint: str) -> str | None:
        return next((g for g in self.feet if g.startswith(joint)), None)

    def _walker_spec(self) -> mujoco.MjSpec:
        """The walker's own MJCF as an MjSpec, root at the origin."""
        spec = mujoco.MjSpec.from_string(walker_xml(self.builder))
        spec.njmax = spec.nconmax = -1  # the arena sizes its own buffers
        spec.body(self.root).pos = [0.0, 0.0, 0.0]
        return spec

    def _adapted_spec(self) -> mujoco.MjSpec:
        spec = self._walker_spec()
        spec.modelname = self.name.replace(":", "_")
        for geom in spec.geoms:
            geom.contype, geom.conaffinity, geom.group = 0, 1, 1
        for sensor in list(spec.sensors):
            spec.delete(sensor)
        for actuator in list(spec.actuators):
            joint, gear = actuator.target, _max_torque(actuator)
            spec.delete(actuator)
            servo = spec.add_actuator(name=joint, target=joint)
            servo.trntype = mujoco.mjtTrn.mjTRN_JOINT
            servo.gear[0] = gear
            # force = k*ctrl - (k/gear)*(gear*qvel) = k*(ctrl - qvel): ctrl is a joint speed
            k = SERVO_GAIN / gear
            servo.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            servo.gainprm[0] = k
            servo.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            servo.biasprm[:3] = [0.0, 0.0, -k / gear]
            servo.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
            servo.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            servo.forcerange = [-1.0, 1.0]
        return spec

    @staticmethod
    def _extent(spec: mujoco.MjSpec) -> tuple[np.ndarray, np.ndarray]:
        """World-space bounding box of the walker's geoms at rest (root at the origin)."""
        model = spec.compile()
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        centres = data.geom_xpos + np.einsum(
            "gij,gj->gi", data.geom_xmat.reshape(-1, 3, 3), model.geom_aabb[:, :3]
        )
        half = np.abs(data.geom_xmat.reshape(-1, 3, 3)) @ model.geom_aabb[:, 3:, None]
        half = half[..., 0]
        return (centres - half).min(axis=0), (centres + half).max(axis=0)

    def template_spec(self) -> mujoco.MjSpec:
        return self._adapted_spec()


class Ant(DmcWalker):
    """dm_control's Ant: a sphere torso on four 2-joint legs (gear 75), omnidirectional."""

    name = "dmc:ant"
    builder = staticmethod(_ant)
    root = "torso"
    critical = ("torso_geom",)
    feet = tuple(
        f"{leg}_ankle_geom" for leg in ("front_left", "front_right", "back_right", "back_left")
    )
    speeds = {"ankle": 6.0}


class CMUHumanoid(DmcWalker):
    """dm_control's CMU humanoid (V2020): 56 actuated hinges, joint torque limits 20-300 N.m.

    Its MJCF is modelled lying down (y up); dm_control stands it up with the root orientation
    `upright_pose`. acl3d's root joints must be world-aligned, so the walker is attached, turned
    upright, under a light world-aligned "base" body that becomes the root.
    """

    name = "dmc:cmu_humanoid"
    builder = staticmethod(_cmu_humanoid)
    root = "base"
    walker_root = "root"
    upright_quat = (0.859, 1.0, 1.0, 0.859)  # dm_control's CMU upright pose (unnormalised)
    critical = tuple(f"cmu/{g}" for g in ("root_geom", "lowerback", "upperback", "thorax", "head"))
    head_angle_reward = False

    def _walker_spec(self) -> mujoco.MjSpec:
        walker = mujoco.MjSpec.from_string(walker_xml(self.builder))
        walker.njmax = walker.nconmax = -1
        walker.body(self.walker_root).pos = [0.0, 0.0, 0.0]
        spec = mujoco.MjSpec()
        base = spec.worldbody.add_body(name=self.root, mass=0.01, inertia=[1e-4, 1e-4, 1e-4])
        quat = np.asarray(self.upright_quat) / np.linalg.norm(self.upright_quat)
        spec.attach(walker, frame=base.add_frame(quat=quat), prefix="cmu/")
        return spec
