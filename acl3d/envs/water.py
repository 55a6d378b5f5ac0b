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
        self._centre = model.geom_aabb[geoms, :3]
        self.bodies = model.geom_bodyid[geoms]
        self._tree_root = model.body_rootid[self.bodies]
        self.body_ids = np.unique(self.bodies)
        self._gravity = -float(model.opt.gravity[2])
        self._wet = False
        self._push_joint, self._push_geom = self._push_tables(model)

    def _push_tables(self, model):
        """For each geom on a body moved by an actuated hinge: that joint (else -1)."""
        actuated = {int(model.actuator_trnid[a, 0]) for a in range(model.nu)}
        joint = np.full(len(self.geoms), -1)
        for i, b in enumerate(self.bodies):
            for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b]):
                if j in actuated and model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE:
                    joint[i] = j
        rows = np.flatnonzero(joint >= 0)
        return joint[rows], rows

    def submerged(self, z) -> np.ndarray:
        return np.asarray(z) <= self.level

    def apply(self, data: mujoco.MjData) -> float:
        """Write this step's water forces into data.xfrc_applied; return the submerged area."""
        g = self.geoms
        xmat = data.geom_xmat[g].reshape(-1, 3, 3)
        rows = np.arange(len(g))
        u = xmat[rows, :, self._k1][:, [0, 2]]  # in-plane axes, x-z components
        w = xmat[rows, :, self._k2][:, [0, 2]]
        centre = data.geom_xpos[g] + np.einsum("gij,gj->gi", xmat, self._centre)
        e1, e2 = self._e1, self._e2
        half_z = np.abs(u[:, 1]) * e1 + np.abs(w[:, 1]) * e2
        bottom = centre[:, 2] - half_z
        if not np.any(bottom < self.level):
            if self._wet:
                data.xfrc_applied[self.body_ids] = 0.0
                self._wet = False
            return 0.0
        self._wet = True
        frac = np.clip((self.level - bottom) / (2 * half_z + 1e-9), 0.0, 1.0)
        rho = self.density
        force = np.zeros((len(g), 2))  # x-z force on each geom
        point = centre[:, [0, 2]].copy()  # where it acts

        # buoyancy, at the centre of the submerged slice
        buoy = rho * self.area * frac * self._gravity
        point_b = point.copy()
        point_b[:, 1] = (bottom + np.minimum(bottom + 2 * half_z, self.level)) / 2

        # the four edges of each rectangle: outward normal n, tangent t, length L, midpoint m
        normals = np.stack((u, -u, w, -w), axis=1)  # (G, 4, 2)
        lengths = np.stack((2 * e2, 2 * e2, 2 * e1, 2 * e1), axis=1)
        offsets = np.stack((e1, e1, e2, e2), axis=1)[..., None] * normals
        mids = point[:, None, :] + offsets
        tangents = np.stack((-normals[..., 1], normals[..., 0]), axis=-1)

        # velocity of each edge midpoint (rigid body motion of the geom's body)
        cvel = data.cvel[self.bodies]
        com = data.subtree_com[self._tree_root]
        rel = np.zeros((len(g), 4, 3))
        rel[..., [0, 2]] = mids - com[:, None, [0, 2]]
        rel[..., 1] = -com[:, None, 1] + centre[:, None, 1]
        vel = cvel[:, None, 3:] + np.cross(cvel[:, None, :3], rel)
        v = vel[..., [0, 2]]
        speed = np.linalg.norm(v, axis=-1)
        vhat = v / np.maximum(speed, 1e-9)[..., None]
        n_v = np.einsum("gek,gek->ge", normals, vhat)
        t_v = np.einsum("gek,gek->ge", tangents, vhat)
        lead = (n_v >= 0) & (speed > 1e-6)
        base = np.where(lead, lengths * rho * speed**2, 0.0) * frac[:, None]
        drag = np.minimum(DRAG_MOD * n_v * base, MAX_DRAG)
        lift = np.minimum(LIFT_MOD * n_v * t_v * base, MAX_LIFT)
        perp = np.stack((-vhat[..., 1], vhat[..., 0]), axis=-1)
        edge_force = -drag[..., None] * vhat + lift[..., None] * perp  # (G, 4, 2)

        forces, points = [force + np.array([0.0, 1.0]) * buoy[:, None]], [point_b]
        forces.append(edge_force.reshape(-1, 2))
        points.append(mids.reshape(-1, 2))
        owners = [rows, np.repeat(rows, 4)]
        if len(self._push_geom):
            push, anchor, which = self._push(data, normals, lengths, frac)
            forces.append(push)
            points.append(anchor)
            owners.append(which)
        self._accumulate(
            data, np.concatenate(forces), np.concatenate(points), np.concatenate(owners)
        )
        return float((self.area * frac).sum())

    def _push(self, data, normals, lengths, frac):
        """Swimming thrust: reaction of the water to each motor's torque, at the joint anchor."""
        rows, joints = self._push_geom, self._push_joint
        m = self.model
        dof = m.jnt_dofadr[joints]
        qpos = data.qpos[m.jnt_qposadr[joints]]
        lo, hi = m.jnt_range[joints, 0], m.jnt_range[joints, 1]
        inside = ~m.jnt_limited[joints].astype(bool) | ((qpos > lo) & (qpos < hi))
        axis = data.xaxis[joints]
        # hinge torque as a 2D (counter-clockwise seen from -y) torque
        tau = data.qfrc_actuator[dof] * -axis[:, 1]
        omega = data.qvel[dof] * -axis[:, 1]
        inertia = m.body_inertia[self.bodies[rows]].max(axis=1)
        anchor = data.xanchor[joints][:, [0, 2]]
        lever = data.xipos[self.bodies[rows]][:, [0, 2]] - anchor
        f = tau[:, None] * np.stack((-lever[:, 1], lever[:, 0]), axis=1)
        n_f = np.einsum("gek,gk->ge", normals[rows], f)
        mag = np.where(n_f > 0, n_f * PUSH_MOD * lengths[rows] * self.density, 0.0)
        mag *= ((tau + inertia * omega) ** 2)[:, None]
        per_edge = np.clip(-mag[..., None] * f[:, None, :], -self.push_clip, self.push_clip)
        push = per_edge.sum(axis=1) * (frac[rows] * inside)[:, None]
        return push, anchor, rows

    def _accumulate(self, data, forces, points, owners) -> None:
        """Sum x-z forces applied at x-z points into each body's xfrc_applied (force + torque)."""
        bodies = self.bodies[owners]
        xipos = data.xipos[bodies]
        arm_x = points[:, 0] - xipos[:, 0]
        arm_z = points[:, 1] - xipos[:, 2]
        torque_y = arm_z * forces[:, 0] - arm_x * forces[:, 1]
        out = data.xfrc_applied
        out[self.body_ids] = 0.0
        nb = self.model.nbody
        out[:, 0] += np.bincount(bodies, forces[:, 0], nb)
        out[:, 2] += np.bincount(bodies, forces[:, 1], nb)
        out[:, 4] += np.bincount(bodies, torque_y, nb)

    def clear(self, data: mujoco.MjData) -> None:
        data.xfrc_applied[self.body_ids] = 0.0
        self._wet = False
