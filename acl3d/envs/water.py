"""Still water below a level: buoyancy, drag, lift and swimming thrust on a body.

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
        area = math.pi * size[0] ** 2  # axis across the track: a disc seen from the side
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
        self._rbound = model.geom_rbound[geoms]
        self.bodies = model.geom_bodyid[geoms]
        self.body_ids = np.unique(self.bodies)
        self._gravity = -float(model.opt.gravity[2])
        self._wet = False
        self._tree_roots = model.body_rootid[self.bodies]
        push = self._push_tables(model)
        # one tuple of plain Python numbers per geom: what apply() needs, read once here
        self._rows = [
            (
                tuple(float(v) for v in model.geom_aabb[g, :3]),
                int(self.bodies[i]),
                int(self._k1[i]),
                int(self._k2[i]),
                float(self._e1[i]),
                float(self._e2[i]),
                float(self.area[i]),
                push.get(i),
            )
            for i, g in enumerate(geoms)
        ]

    def _push_tables(self, model: mujoco.MjModel) -> dict[int, tuple]:
        """Geom index -> the actuated hinge moving its body: (joint, dof, qpos address, unlimited,
        low, high, body inertia)."""
        actuated = {int(model.actuator_trnid[a, 0]) for a in range(model.nu)}
        tables = {}
        for i, b in enumerate(self.bodies):
            for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b]):
                if j in actuated and model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE:
                    tables[i] = (
                        int(j),
                        int(model.jnt_dofadr[j]),
                        int(model.jnt_qposadr[j]),
                        not bool(model.jnt_limited[j]),
                        float(model.jnt_range[j, 0]),
                        float(model.jnt_range[j, 1]),
                        float(model.body_inertia[b].max()),
                    )
        return tables

    def apply(self, data: mujoco.MjData) -> float:
        """Write this step's water forces into data.xfrc_applied; return the submerged area.

        Plain Python floats over the few geoms of a body: 3-4x faster than numpy on arrays
        this small.
        """
        if (data.geom_xpos[self.geoms, 2] - self._rbound).min() >= self.level:
            if self._wet:  # dry: nothing reaches the water
                self.clear(data)
            return 0.0
        self._wet = True
        level, rho, gravity = self.level, self.density, self._gravity
        xpos = data.geom_xpos[self.geoms].tolist()  # one read per array, then plain floats
        xmat = data.geom_xmat[self.geoms].tolist()
        cvel = data.cvel[self.bodies].tolist()
        com = data.subtree_com[self._tree_roots].tolist()
        xipos = data.xipos[self.bodies].tolist()
        per_body: dict[int, list[float]] = {}
        wet_area = 0.0
        for i, ((c0, c1, c2), b, k1, k2, e1, e2, area, push) in enumerate(self._rows):
            r = xmat[i]
            px, py, pz = xpos[i]
            px += r[0] * c0 + r[1] * c1 + r[2] * c2  # the bounding box centre
            py += r[3] * c0 + r[4] * c1 + r[5] * c2
            pz += r[6] * c0 + r[7] * c1 + r[8] * c2
            ux, uz, wx, wz = r[k1], r[6 + k1], r[k2], r[6 + k2]  # in-plane axes, x-z parts
            half_z = abs(uz) * e1 + abs(wz) * e2
            bottom = pz - half_z
            if bottom >= level:
                continue
            frac = min(1.0, (level - bottom) / (2 * half_z + 1e-9))
            wet_area += area * frac
            w_x, w_y, w_z, v_x, _, v_z = cvel[i]
            cx, cy, cz = com[i]
            ax, _, az = xipos[i]
            buoyancy = rho * area * frac * gravity  # vertical, through the centre
            fx_sum, fz_sum, ty_sum = 0.0, buoyancy, -(px - ax) * buoyancy
            ry = py - cy
            # the rectangle's edges: outward normal (nx, nz), half extent to the edge, length
            edges = (
                (ux, uz, e1, 2 * e2),
                (-ux, -uz, e1, 2 * e2),
                (wx, wz, e2, 2 * e1),
                (-wx, -wz, e2, 2 * e1),
            )
            for nx, nz, offset, length in edges:
                mx, mz = px + offset * nx, pz + offset * nz  # edge midpoint and its velocity
                vx = v_x + w_y * (mz - cz) - w_z * ry
                vz = v_z + w_x * ry - w_y * (mx - cx)
                speed2 = vx * vx + vz * vz
                if speed2 < 1e-18:
                    continue
                inv = 1.0 / math.sqrt(speed2)
                n_v = (nx * vx + nz * vz) * inv
                if n_v <= 0.0:  # trailing edge
                    continue
                t_v = (nx * vz - nz * vx) * inv  # tangent (-nz, nx) . v_hat
                base = length * rho * speed2 * frac
                drag = min(DRAG_MOD * n_v * base, MAX_DRAG)
                lift = min(LIFT_MOD * n_v * t_v * base, MAX_LIFT)
                fx = (-drag * vx - lift * vz) * inv  # -drag v_hat + lift perp(v_hat)
                fz = (-drag * vz + lift * vx) * inv
                fx_sum += fx
                fz_sum += fz
                ty_sum += (mz - az) * fx - (mx - ax) * fz
            if push is not None:
                fx, fz, ty = self._push(data, push, edges, frac, ax, az)
                fx_sum += fx
                fz_sum += fz
                ty_sum += ty
            acc = per_body.setdefault(b, [0.0, 0.0, 0.0])
            acc[0] += fx_sum
            acc[1] += fz_sum
            acc[2] += ty_sum
        out = data.xfrc_applied
        out[self.body_ids] = 0.0
        for b, (fx, fz, ty) in per_body.items():
            out[b, 0], out[b, 2], out[b, 4] = fx, fz, ty
        return wet_area

    def _push(self, data, push, edges, frac, ax, az) -> tuple[float, float, float]:
        """Swimming thrust: the water's reaction to a motor's torque, applied at its joint anchor.

        Returns (force x, force z, torque y about the body's centre of mass).
        """
        joint, dof, qpos_adr, free, low, high, inertia = push
        q = data.qpos.item(qpos_adr)
        if not (free or low < q < high):
            return 0.0, 0.0, 0.0
        sign = -data.xaxis.item(joint, 1)  # hinge torque as a 2D counter-clockwise torque
        tau = data.qfrc_actuator.item(dof) * sign
        omega = data.qvel.item(dof) * sign
        anchor_x, _, anchor_z = data.xanchor[joint].tolist()
        f_x, f_z = -tau * (az - anchor_z), tau * (ax - anchor_x)  # tau * perp(lever)
        gain = PUSH_MOD * self.density * (tau + inertia * omega) ** 2
        clip = self.push_clip
        px = pz = 0.0
        for nx, nz, _, length in edges:
            n_f = nx * f_x + nz * f_z
            if n_f > 0.0:
                magnitude = n_f * length * gain
                px += min(clip, max(-clip, -magnitude * f_x))
                pz += min(clip, max(-clip, -magnitude * f_z))
        px, pz = px * frac, pz * frac
        return px, pz, (anchor_z - az) * px - (anchor_x - ax) * pz

    def clear(self, data: mujoco.MjData) -> None:
        data.xfrc_applied[self.body_ids] = 0.0
        self._wet = False

    @property
    def wet(self) -> bool:
        """Forces were written last step (the next dry step clears them): part of env state."""
        return self._wet

    @wet.setter
    def wet(self, value: bool) -> None:
        self._wet = bool(value)
