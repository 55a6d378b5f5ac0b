"""Still water below a level: buoyancy, drag, lift and swimming thrust on a body, in numpy.

MuJoCo's fluid model is global and has no buoyancy, so Parkour computes its own forces each
control step and writes them to `data.xfrc_applied` (they act during the whole control step, as
the original applies its forces once per Box2D step). TeachMyAgent's water works on 2D polygons
(§2.5 of the reference); here each body geom is reduced to its sagittal (x-z) rectangle, so the
original formulas apply edge by edge with densities in the original's units (mass per m² of the
2D shape: the acl3d bodies keep the original masses, so a part of 2D density < 1 floats):

* buoyancy  rho * A * f * g upwards, A = the geom's x-z silhouette area, f = submerged fraction;
* drag      min((n.v) * 0.25 * L * rho * |v|^2, 2000) against v, per leading edge (n.v >= 0);
* lift      min((n.v)(e.v) * 0.25 * L * rho * |v|^2, 500) perpendicular to v;
* push      for a part driven by a hinge inside its limits, the reaction of the water to the
            motor torque tau: per edge facing f = tau * perp(lever), -(n.f) 0.05 L rho
            (tau + I w)^2 f clipped to +-20 per component, at the joint anchor (the fish's
            thrust; with these constants it is nearly always at the clip).

Partly submerged geoms get their drag, lift and push scaled by f (the original clips the polygon
against the water; a linear fraction is the 3D shortcut). Nothing is computed while no geom
reaches the water, so walkers on dry ground pay almost nothing.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

WATER_DENSITY = 1.0  # kg per m^2 of 2D silhouette, the original's units
DRAG_MOD, LIFT_MOD, PUSH_MOD = 0.25, 0.25, 0.05
MAX_DRAG, MAX_LIFT = 2000.0, 500.0
PUSH_CLIP = 20.0  # the original's water_clip


def _mesh_volume(model: mujoco.MjModel, mesh_id: int) -> float:
    """Volume of a closed triangle mesh (divergence theorem)."""
    v0, nv = model.mesh_vertadr[mesh_id], model.mesh_vertnum[mesh_id]
    f0, nf = model.mesh_faceadr[mesh_id], model.mesh_facenum[mesh_id]
    verts = model.mesh_vert[v0 : v0 + nv]
    tri = verts[model.mesh_face[f0 : f0 + nf]]
    return abs(float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6)


def silhouette(model: mujoco.MjModel, geom: int) -> tuple[int, int, float]:
    """(in-plane axis 1, in-plane axis 2, x-z silhouette area) of a geom in its body frame.

    The geom axis closest to the body's y axis is the thickness axis; the other two span the
    sagittal rectangle whose half extents are the geom's bounding box.
    """
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[geom])
    k_y = int(np.argmax(np.abs(rot.reshape(3, 3)[1])))
    k1, k2 = (k for k in range(3) if k != k_y)
    half = model.geom_aabb[geom, 3:]
    size = model.geom_size[geom]
    kind = model.geom_type[geom]
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        area = math.pi * size[0] ** 2
    elif kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        area = math.pi * half[k1] * half[k2]
    elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE and k_y != 2:
        area = 4 * size[0] * size[1] + math.pi * size[0] ** 2
    elif kind in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER) and k_y == 2:
        area = math.pi * size[0] ** 2  # axis across the track: a disc in profile
    elif kind == mujoco.mjtGeom.mjGEOM_MESH:
        area = _mesh_volume(model, model.geom_dataid[geom]) / (2 * half[k_y])
    else:  # box, cylinder lying in the plane
        area = 4 * half[k1] * half[k2]
    return k1, k2, float(area)


class Water:
    """Water forces on one bound body; `level` (world z of the surface) is set per episode."""

    def __init__(
        self, model: mujoco.MjModel, geom_ids, density: float = WATER_DENSITY, push_clip=PUSH_CLIP
    ):
        self.model = model
        self.density = density
        self.push_clip = push_clip
        self.level = -np.inf
        geoms = np.asarray(
            [g for g in geom_ids if model.geom_contype[g] or model.geom_conaffinity[g]], dtype=int
        )
        self.geoms = geoms
        axes = [silhouette(model, g) for g in geoms]
        self._k1 = np.array([a[0] for a in axes])
        self._k2 = np.array([a[1] for a in axes])
        self.area = np.array([a[2] for a in axes])
        half = model.geom_aabb[geoms, 3:]
        self._e1 = half[np.arange(len(geoms)), self._k1]
        self._e2 = half[np.arange(len(geoms)), self._k2]
        centre = model.geom_aabb[geoms, :3]
        self._centre = centre if np.abs(centre).max(initial=0.0) > 1e-9 else None
        self._rbound = model.geom_rbound[geoms]
        flat = 9 * geoms
        self._axis_index = np.stack(
            (flat + self._k1, flat + 6 + self._k1, flat + self._k2, flat + 6 + self._k2)
        )
        self._lengths = np.column_stack((2 * self._e2, 2 * self._e2, 2 * self._e1, 2 * self._e1))
        self._half_offsets = np.column_stack((self._e1, self._e1, self._e2, self._e2))
        self.bodies = model.geom_bodyid[geoms]
        self._tree_root = model.body_rootid[self.bodies]
        self.body_ids = np.unique(self.bodies)
        self._gravity = -float(model.opt.gravity[2])
        self._wet = False
        self._push_tables(model)

    def _push_tables(self, model: mujoco.MjModel) -> None:
        """Geoms on a body moved by an actuated hinge, and that hinge's indices."""
        actuated = {int(model.actuator_trnid[a, 0]) for a in range(model.nu)}
        joint = np.full(len(self.geoms), -1)
        for i, b in enumerate(self.bodies):
            for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b]):
                if j in actuated and model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE:
                    joint[i] = j
        self._push_rows = np.flatnonzero(joint >= 0)
        j = joint[self._push_rows]
        self._push_joints = j
        self._push_dofs = model.jnt_dofadr[j]
        self._push_qpos = model.jnt_qposadr[j]
        self._push_free = ~model.jnt_limited[j].astype(bool)
        self._push_low, self._push_high = model.jnt_range[j, 0], model.jnt_range[j, 1]
        self._push_inertia = model.body_inertia[self.bodies[self._push_rows]].max(axis=1)

    def submerged(self, z) -> np.ndarray:
        return np.asarray(z) <= self.level

    def apply(self, data: mujoco.MjData) -> float:
        """Write this step's water forces into data.xfrc_applied; return the submerged area."""
        g = self.geoms
        pos = data.geom_xpos[g]
        if (pos[:, 2] - self._rbound).min() >= self.level:  # dry: nothing reaches the water
            if self._wet:
                self.clear(data)
            return 0.0
        self._wet = True
        ux, uz, wx, wz = data.geom_xmat.ravel()[self._axis_index]  # in-plane axes, x-z parts
        centre = (
            pos
            if self._centre is None
            else pos + np.einsum("gij,gj->gi", data.geom_xmat[g].reshape(-1, 3, 3), self._centre)
        )
        cx, cy, cz = centre[:, 0], centre[:, 1], centre[:, 2]
        e1, e2 = self._e1, self._e2
        half_z = np.abs(uz) * e1 + np.abs(wz) * e2
        bottom = cz - half_z
        frac = np.clip((self.level - bottom) / (2 * half_z + 1e-9), 0.0, 1.0)
        rho = self.density

        # buoyancy, vertical through the geom's centre (its height does not change the torque)
        buoy = rho * self.area * frac * self._gravity

        # the four edges of each geom's rectangle: outward normals, lengths, midpoints
        nx = np.column_stack((ux, -ux, wx, -wx))
        nz = np.column_stack((uz, -uz, wz, -wz))
        mx = cx[:, None] + self._half_offsets * nx
        mz = cz[:, None] + self._half_offsets * nz

        # velocity of each edge midpoint (rigid motion of the geom's body), x-z parts
        cvel = data.cvel[self.bodies]
        com = data.subtree_com[self._tree_root]
        rx, rz = mx - com[:, 0:1], mz - com[:, 2:3]
        ry = (cy - com[:, 1])[:, None]
        vx = cvel[:, 3:4] + cvel[:, 1:2] * rz - cvel[:, 2:3] * ry
        vz = cvel[:, 5:6] + cvel[:, 0:1] * ry - cvel[:, 1:2] * rx
        speed2 = vx * vx + vz * vz
        inv = 1.0 / np.maximum(np.sqrt(speed2), 1e-9)
        n_v = (nx * vx + nz * vz) * inv  # n . v_hat
        t_v = (nx * vz - nz * vx) * inv  # t . v_hat, t = (-n_z, n_x)
        base = np.where(n_v > 0.0, self._lengths * rho * speed2, 0.0) * frac[:, None]
        drag = np.minimum(DRAG_MOD * n_v * base, MAX_DRAG)
        lift = np.minimum(LIFT_MOD * n_v * t_v * base, MAX_LIFT)
        fx = (-drag * vx - lift * vz) * inv  # -drag v_hat + lift perp(v_hat)
        fz = (-drag * vz + lift * vx) * inv

        xipos = data.xipos[self.bodies]
        ax, az = xipos[:, 0:1], xipos[:, 2:3]
        force_x = fx.sum(axis=1)
        force_z = fz.sum(axis=1) + buoy
        torque_y = ((mz - az) * fx - (mx - ax) * fz).sum(axis=1) - (cx - ax[:, 0]) * buoy
        if len(self._push_rows):
            self._add_push(data, nx, nz, frac, force_x, force_z, torque_y)
        out = data.xfrc_applied
        out[self.body_ids] = 0.0
        nb = self.model.nbody
        out[:, 0] += np.bincount(self.bodies, force_x, nb)
        out[:, 2] += np.bincount(self.bodies, force_z, nb)
        out[:, 4] += np.bincount(self.bodies, torque_y, nb)
        return float((self.area * frac).sum())

    def _add_push(self, data, nx, nz, frac, force_x, force_z, torque_y) -> None:
        """Swimming thrust: the water's reaction to each motor's torque, at the joint anchor."""
        rows, joints = self._push_rows, self._push_joints
        dof = self._push_dofs
        qpos = data.qpos[self._push_qpos]
        inside = self._push_free | ((qpos > self._push_low) & (qpos < self._push_high))
        sign = -data.xaxis[joints, 1]  # hinge torque as a 2D counter-clockwise torque
        tau = data.qfrc_actuator[dof] * sign
        omega = data.qvel[dof] * sign
        bodies = self.bodies[rows]
        anchor = data.xanchor[joints]
        xipos = data.xipos[bodies]
        lever_x, lever_z = xipos[:, 0] - anchor[:, 0], xipos[:, 2] - anchor[:, 2]
        f_x, f_z = -tau * lever_z, tau * lever_x
        n_f = nx[rows] * f_x[:, None] + nz[rows] * f_z[:, None]
        mag = np.where(n_f > 0.0, n_f * PUSH_MOD * self._lengths[rows] * self.density, 0.0)
        mag *= ((tau + self._push_inertia * omega) ** 2)[:, None]
        clip = self.push_clip
        scale = frac[rows] * inside
        px = np.clip(-mag * f_x[:, None], -clip, clip).sum(axis=1) * scale
        pz = np.clip(-mag * f_z[:, None], -clip, clip).sum(axis=1) * scale
        force_x[rows] += px  # rows are distinct geoms
        force_z[rows] += pz
        arm_x, arm_z = anchor[:, 0] - xipos[:, 0], anchor[:, 2] - xipos[:, 2]
        torque_y[rows] += arm_z * px - arm_x * pz

    def clear(self, data: mujoco.MjData) -> None:
        data.xfrc_applied[self.body_ids] = 0.0
        self._wet = False
