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
against the water; a linear fraction is the 3D shortcut). On the CPU nothing is computed while
no geom of any env reaches the water, so walkers on dry ground pay almost nothing.
"""

from __future__ import annotations

import copy
import math

import mujoco
import numpy as np

from acl3d.envs.array_ops import NUMPY, ArrayOps

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
    """Water forces on one bound body, for N envs or worlds at once; `level` (world z of the
    surface) is a single env's, set per episode.

    Written once over `ArrayOps` (`forces`): numpy in the CPU envs, torch in the many-world
    simulation (`on(ops)`). Each geom's rectangle is worked on as (N, geoms, edges) arrays with
    masks in place of the per-geom and per-edge branches; geom results are summed per body.
    """

    def __init__(
        self, model: mujoco.MjModel, geom_ids, density: float = WATER_DENSITY, push_clip=PUSH_CLIP
    ):
        self.density = density
        self.push_clip = push_clip
        self.level = -np.inf
        self.ops: ArrayOps = NUMPY
        geoms = np.asarray(
            [g for g in geom_ids if model.geom_contype[g] or model.geom_conaffinity[g]], dtype=int
        )
        self.geoms = geoms
        axes = [silhouette(model, g) for g in geoms]
        k1 = np.array([a[0] for a in axes], dtype=int)
        k2 = np.array([a[1] for a in axes], dtype=int)
        self.area = np.array([a[2] for a in axes])
        half = model.geom_aabb[geoms, 3:]
        self._e1 = half[np.arange(len(geoms)), k1]
        self._e2 = half[np.arange(len(geoms)), k2]
        self.reach = model.geom_rbound[geoms]
        self._centre = model.geom_aabb[geoms, :3]  # the bounding box centre in the geom frame
        self.bodies = model.geom_bodyid[geoms]
        self.body_ids = np.unique(self.bodies)
        self._gravity = -float(model.opt.gravity[2])
        self._wet = False
        self._roots = model.body_rootid[self.bodies]
        # geom -> body sums as products with 0/1 matrices (a sum per body, in geom order)
        self._to_body = (self.bodies[:, None] == self.body_ids[None, :]).astype(float)
        # the rectangle's four edges: which in-plane axis is the normal (+/-), half extents; a
        # normal's x and z are the matrix entries (geom, column k) and (geom, 6 + k)
        self._each = np.repeat(np.arange(len(geoms)), 4).reshape(-1, 4)
        self._axis = np.stack((k1, k1, k2, k2), axis=1)
        self._edge_sign = np.array([1.0, -1.0, 1.0, -1.0])
        self._offset = np.stack((self._e1, self._e1, self._e2, self._e2), axis=1)  # (G, 4)
        self._length = 2 * np.stack((self._e2, self._e2, self._e1, self._e1), axis=1)
        self._push_tables(model)

    def _push_tables(self, model: mujoco.MjModel) -> None:
        """The geoms whose body an actuated hinge moves, and that hinge: joint, dof, qpos
        address, unlimited, range, the body's largest inertia."""
        actuated = {int(model.actuator_trnid[a, 0]) for a in range(model.nu)}
        tables = {}  # geom index -> its body's (last) actuated hinge
        for i, b in enumerate(self.bodies):
            for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b]):
                if j in actuated and model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE:
                    tables[i] = (j, model.jnt_dofadr[j], model.jnt_qposadr[j],
                                 not model.jnt_limited[j], *model.jnt_range[j],
                                 model.body_inertia[b].max())  # fmt: skip
        pushed, table = list(tables), list(tables.values())
        self._pushed = np.array(pushed, dtype=int)
        self._select = (self._pushed[:, None] == np.arange(len(self.geoms))).astype(float)
        columns = list(zip(*table)) if table else [()] * 7
        self._joint, self._dof, self._qadr = (np.array(c, dtype=int) for c in columns[:3])
        self._free = np.array(columns[3], dtype=bool)
        self._low, self._high, self._inertia = (np.array(c, dtype=float) for c in columns[4:])

    def on(self, ops: ArrayOps) -> Water:
        """These forces computed on arrays of `ops` (the many-world simulation's tensors)."""
        out = copy.copy(self)
        out.ops = ops
        for name in ("area", "_e1", "_e2", "_centre", "_to_body", "_edge_sign", "_offset",
                     "_length", "_select", "_low", "_high", "_inertia"):  # fmt: skip
            setattr(out, name, ops.asarray(getattr(self, name)))
        for name in ("geoms", "bodies", "_roots", "_each", "_axis", "_pushed", "_joint", "_dof",
                     "_qadr", "body_ids"):  # fmt: skip
            setattr(out, name, ops.index(getattr(self, name)))
        out._free = ops.index(self._free.astype(int)) > 0
        return out

    def forces(self, physics, level):
        """(N, bodies, 3) forces (fx, fz, torque y about each body's centre of mass) of the
        water at `level` (N,) on the bodies `body_ids` of N envs, and (N,) submerged areas."""
        ops, xp = self.ops, self.ops.xp
        xmat = physics.field("geom_xmat")[:, self.geoms]
        n, g = xmat.shape[0], xmat.shape[1]
        r = xmat.reshape(n, g, 9)
        p = physics.field("geom_xpos")[:, self.geoms] + xp.einsum(
            "ngij,gj->ngi", r.reshape(n, g, 3, 3), self._centre
        )
        px, py, pz = p[..., 0], p[..., 1], p[..., 2]
        # the edges' outward normals (N, G, 4): the in-plane axes' x-z parts, signed
        nx = r[:, self._each, self._axis] * self._edge_sign
        nz = r[:, self._each, self._axis + 6] * self._edge_sign
        half_z = xp.abs(nz[..., 0]) * self._e1 + xp.abs(nz[..., 2]) * self._e2
        bottom = pz - half_z
        level = level[:, None]
        wet = bottom < level
        frac = ops.clip((level - bottom) / (2 * half_z + 1e-9), high=1.0)
        frac = xp.where(wet, frac, 0.0)
        cvel = physics.field("cvel")[:, self.bodies]
        com = physics.field("subtree_com")[:, self._roots]
        ipos = physics.field("xipos")[:, self.bodies]
        ax, az = ipos[..., 0], ipos[..., 2]
        buoyancy = self.density * self.area * frac * self._gravity  # vertical, at the centre
        ry = py - com[..., 1]
        # each edge's midpoint (mx, mz) and that point's velocity
        mx, mz = px[..., None] + self._offset * nx, pz[..., None] + self._offset * nz
        w_x, w_y, w_z = cvel[..., 0:1], cvel[..., 1:2], cvel[..., 2:3]
        vx = cvel[..., 3:4] + w_y * (mz - com[..., 2:3]) - (w_z[..., 0] * ry)[..., None]
        vz = cvel[..., 5:6] + (w_x[..., 0] * ry)[..., None] - w_y * (mx - com[..., 0:1])
        speed2 = vx * vx + vz * vz
        inv = 1.0 / xp.sqrt(ops.clip(speed2, low=1e-18))
        n_v = (nx * vx + nz * vz) * inv
        leading = (speed2 >= 1e-18) & (n_v > 0.0)  # trailing edges feel nothing
        t_v = (nx * vz - nz * vx) * inv  # tangent (-nz, nx) . v_hat
        base = self._length * self.density * speed2 * frac[..., None]
        drag = ops.clip(DRAG_MOD * n_v * base, high=MAX_DRAG)
        lift = ops.clip(LIFT_MOD * n_v * t_v * base, high=MAX_LIFT)
        fx = xp.where(leading, (-drag * vx - lift * vz) * inv, 0.0)  # -drag v + lift perp(v)
        fz = xp.where(leading, (-drag * vz + lift * vx) * inv, 0.0)
        torque = (mz - az[..., None]) * fx - (mx - ax[..., None]) * fz
        per_geom = _columns(
            xp, fx.sum(axis=2), buoyancy + fz.sum(axis=2), torque.sum(axis=2) - (px - ax) * buoyancy
        )
        if self._pushed.shape[0]:
            push = self._push(physics, nx, nz, frac, ax, az)  # (N, pushed, 3)
            per_geom = per_geom + xp.einsum("npk,pg->ngk", push, self._select)
        return xp.einsum("ngk,gb->nbk", per_geom, self._to_body), (self.area * frac).sum(axis=1)

    def _push(self, physics, nx, nz, frac, ax, az):
        """(N, pushed geoms, 3) swimming thrust: the water's reaction to the motors' torques,
        at their joint anchors."""
        ops, xp, g = self.ops, self.ops.xp, self._pushed
        q = physics.field("qpos")[:, self._qadr]
        active = self._free | ((self._low < q) & (q < self._high))
        sign = -physics.field("xaxis")[:, self._joint, 1]  # the hinge's 2D counter-clockwise
        tau = physics.field("qfrc_actuator")[:, self._dof] * sign
        omega = physics.field("qvel")[:, self._dof] * sign
        anchor = physics.field("xanchor")[:, self._joint]
        ax, az = ax[:, g], az[:, g]
        f_x, f_z = -tau * (az - anchor[..., 2]), tau * (ax - anchor[..., 0])  # tau perp(lever)
        gain = PUSH_MOD * self.density * (tau + self._inertia * omega) ** 2
        n_f = nx[:, g] * f_x[..., None] + nz[:, g] * f_z[..., None]
        magnitude = xp.where(n_f > 0.0, n_f * self._length[g] * gain[..., None], 0.0)
        clip = self.push_clip
        push_x = ops.clip(-magnitude * f_x[..., None], -clip, clip).sum(axis=2)
        push_z = ops.clip(-magnitude * f_z[..., None], -clip, clip).sum(axis=2)
        push_x = xp.where(active, push_x * frac[:, g], 0.0)
        push_z = xp.where(active, push_z * frac[:, g], 0.0)
        torque = (anchor[..., 2] - az) * push_x - (anchor[..., 0] - ax) * push_z
        return _columns(xp, push_x, push_z, torque)

    def apply(self, data: mujoco.MjData) -> float:
        """One env: write this step's water forces into `data.xfrc_applied` (cleared once the
        body has left the water); return the submerged area."""
        reached = (data.geom_xpos[self.geoms, 2] - self.reach).min() < self.level
        if not (reached or self._wet):
            return 0.0
        forces, area = self.forces(_OneData(data), np.array([self.level]))
        data.xfrc_applied[self.body_ids, 0::2] = forces[0]
        self._wet = bool(reached)
        return float(area[0])

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


def _columns(xp, *arrays):
    """(..., k) from k arrays (...): `stack` on the last axis (numpy's `stack` costs 6 us)."""
    return xp.concatenate([a[..., None] for a in arrays], axis=-1)


class _OneData:
    """An MjData read as a physics backend of one env (`field(name)`: (1, ...) views)."""

    def __init__(self, data: mujoco.MjData):
        self.data = data

    def field(self, name: str) -> np.ndarray:
        return getattr(self.data, name)[None]
