"""Bodies: an MJCF template per embodiment plus the Python description the tracks' rules need.

A `Body` says which joints it drives (and how fast), its torque, its torque penalty, which of its
geoms end the episode on contact, which report contact in the observation, and how high it
spawns. `Body.spec()` gives the MjSpec to attach to an arena (root joints added: planar
slide-x/slide-z/hinge-y like Walker2d, or a free joint); `BoundBody` resolves names to indices in
a compiled model once, so the per-step work is plain numpy indexing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import mujoco
import numpy as np

from acl3d import validation
from acl3d.assets import mjcf_path

TORQUE_PENALTY = (
    0.00035  # TeachMyAgent, multiplied by 80 for every body (see §2.1 of the reference)
)
PREFIX = "walker/"  # name prefix of everything a body brings into the arena


@dataclass(frozen=True)
class Motor:
    """One actuated joint: the velocity servo runs at `speed` rad/s with torque <= torque*|a|."""

    joint: str
    speed: float
    angle_correction: float = (
        0.0  # added to the angle in the observation (knees: +1, as the original)
    )
    contact_geom: str | None = (
        None  # if set, the motor state carries this geom's ground contact flag
    )


@dataclass(frozen=True)
class GraspSensor:
    """A climber's hand sensor: the geom that must touch a graspable surface, and its body.

    The geom is a non-colliding sphere (radius 0.05 m, contype = conaffinity = 0) at the hand tip:
    it never pushes anything, so grasp logic (Parkour) tests it against graspable geoms itself
    (e.g. `mujoco.mj_geomDistance`) and welds `body` to what it holds.
    """

    geom: str
    body: str


class Body:
    """Description of one embodiment; subclasses set the class attributes (and may build procedurally)."""

    name: ClassVar[str]
    kind: ClassVar[str] = "walker"  # walker | climber | swimmer | amphibian
    template: ClassVar[str]  # path under mjcf/
    root: ClassVar[str] = "hull"  # the "head": lidar origin, reward x, observed angle/velocities
    motors: ClassVar[tuple[Motor, ...]]
    torque: ClassVar[float] = 80.0
    penalty_divisor: ClassVar[float] = 1.0  # TeachMyAgent divides the torque penalty per body
    critical_geoms: ClassVar[tuple[str, ...]] = ()
    head_angle_reward: ClassVar[bool] = True
    planar_default: ClassVar[bool] = True
    spawn_height: ClassVar[float]  # root height above the ground at spawn, metres
    length: ClassVar[float] = 2.0  # extent along x, to size the start pad
    grasp_sensors: ClassVar[tuple[GraspSensor, ...]] = ()
    # physics steps per 50 Hz control step (timestep 0.02 / frame_skip)
    frame_skip: ClassVar[int] = 2
    initial_push: ClassVar[bool] = True  # the original pushes every body but the fish at spawn

    def __init__(self, planar: bool | None = None, motors_torque: float | None = None):
        planar = validation.optional_flag("planar", planar)
        self.planar = self.planar_default if planar is None else planar
        if motors_torque is not None:
            self.torque = validation.real("motors_torque", motors_torque, 1.0, 10_000.0)

    @property
    def action_size(self) -> int:
        return len(self.motors) + len(self.grasp_sensors)

    @property
    def torque_cost_per_unit(self) -> float:
        """Reward cost of |a| = 1 on one action entry (grasp entries included, as the original)."""
        return TORQUE_PENALTY * 80.0 / self.penalty_divisor

    def template_spec(self) -> mujoco.MjSpec:
        """The body's MJCF template; procedurally generated bodies override this."""
        return mujoco.MjSpec.from_file(str(mjcf_path(self.template)))

    def spec(self) -> mujoco.MjSpec:
        """The template with its root joints: sagittal-plane (default) or free-floating."""
        spec = self.template_spec()
        root = spec.body(self.root)
        if self.planar:
            for name, jtype, axis in (
                ("root_x", mujoco.mjtJoint.mjJNT_SLIDE, (1, 0, 0)),
                ("root_z", mujoco.mjtJoint.mjJNT_SLIDE, (0, 0, 1)),
                ("root_pitch", mujoco.mjtJoint.mjJNT_HINGE, (0, -1, 0)),
            ):
                j = root.add_joint(name=name, type=jtype, axis=axis)
                j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
                j.armature = 0.0
        else:
            root.add_freejoint(name="root")
        return spec

    def describe(self) -> dict:
        return {
            "name": self.name,
            "kind": self.kind,
            "planar": self.planar,
            "actions": self.action_size,
            "torque": self.torque,
        }


@dataclass
class BoundBody:
    """A body's indices in one compiled model: everything the per-step code reads or writes."""

    body: Body
    model: mujoco.MjModel
    root_id: int = field(init=False)
    qpos_adr: np.ndarray = field(init=False)
    dof_adr: np.ndarray = field(init=False)
    speeds: np.ndarray = field(init=False)
    angle_correction: np.ndarray = field(init=False)
    contact_geom_ids: np.ndarray = field(init=False)
    has_contact_flag: np.ndarray = field(init=False)
    critical_geom_ids: np.ndarray = field(init=False)
    body_geom_ids: np.ndarray = field(init=False)
    root_qpos: int = field(init=False)
    root_dof: int = field(init=False)

    def __post_init__(self):
        m, b = self.model, self.body

        def jid(name):
            return m.joint(PREFIX + name).id

        def gid(name):
            return m.geom(PREFIX + name).id

        self.root_id = m.body(PREFIX + b.root).id
        joints = [jid(mo.joint) for mo in b.motors]
        self.qpos_adr = m.jnt_qposadr[joints].copy()
        self.dof_adr = m.jnt_dofadr[joints].copy()
        self.speeds = np.array([mo.speed for mo in b.motors])
        self.angle_correction = np.array([mo.angle_correction for mo in b.motors])
        self.has_contact_flag = np.array([mo.contact_geom is not None for mo in b.motors])
        self.contact_geom_ids = np.array(
            [gid(mo.contact_geom) for mo in b.motors if mo.contact_geom], dtype=int
        )
        self.critical_geom_ids = np.array([gid(g) for g in b.critical_geoms], dtype=int)
        self.actuator_ids = np.array(
            [m.actuator(PREFIX + mo.joint).id for mo in b.motors], dtype=int
        )
        root_joint = m.joint(PREFIX + ("root_x" if b.planar else "root"))
        self.root_qpos = int(root_joint.qposadr[0])
        self.root_dof = int(root_joint.dofadr[0])
        subtree = [i for i in range(m.nbody) if self._in_subtree(i)]
        self.body_geom_ids = np.array(
            [g for g in range(m.ngeom) if m.geom_bodyid[g] in subtree], dtype=int
        )
        self.total_mass = float(m.body_subtreemass[self.root_id])
        self.home = m.body_pos[self.root_id].copy()  # spawn position compiled into the model
        limited = m.jnt_limited[joints].astype(bool)
        low, high = m.jnt_range[joints, 0], m.jnt_range[joints, 1]
        # joints start at 0 rad, or at the nearest limit when 0 is outside their range
        self.initial_angles = np.where(limited, np.clip(0.0, low, high), 0.0)

    def _in_subtree(self, body_id: int) -> bool:
        while body_id > 0:
            if body_id == self.root_id:
                return True
            body_id = self.model.body_parentid[body_id]
        return False

    @property
    def motor_state_size(self) -> int:
        return 2 * len(self.body.motors) + int(self.has_contact_flag.sum())

    def place(self, data: mujoco.MjData, x: float, z: float) -> None:
        """Put the root at world (x, z), upright, joints at their initial angles.

        Planar root slides measure displacement from the compiled spawn position; a free
        joint's position is absolute.
        """
        q = self.root_qpos
        if self.body.planar:
            data.qpos[q] = x - self.home[0]
            data.qpos[q + 1] = z - self.home[2]
            data.qpos[q + 2] = 0.0
        else:
            data.qpos[q : q + 3] = (x, 0.0, z)
            data.qpos[q + 3 : q + 7] = (1.0, 0.0, 0.0, 0.0)
        data.qpos[self.qpos_adr] = self.initial_angles
