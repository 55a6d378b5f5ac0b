"""Parkour's water on torch tensors: `Water.apply` (buoyancy, drag, lift, swimming thrust) for N
worlds at once.

The same formulas, edge by edge of each body geom's sagittal rectangle (`acl3d.envs.water`), as
(N, geoms, edges) tensor arithmetic with masks in place of the per-geom branches, summed per body;
in float64 it equals `Water.apply` to rounding; tests/test_many_worlds_parkour.py checks it in
float32 on Warp worlds (1e-4 relative).
"""

from __future__ import annotations

import torch

from acl3d.envs.water import DRAG_MOD, LIFT_MOD, MAX_DRAG, MAX_LIFT, PUSH_MOD, Water
from acl3d.sim.worlds import Simulation


def _index(values, device) -> torch.Tensor:
    return torch.as_tensor(values, dtype=torch.long, device=device)


class TensorWater:
    """`Water.apply` for N worlds: (N, bodies, 3) forces (fx, fz, torque y) on `body_ids`."""

    def __init__(self, water: Water, device, dtype):
        f = {"device": device, "dtype": dtype}
        rows = water._rows
        self.density, self.clip, self.gravity = water.density, water.push_clip, water._gravity
        self.geoms = _index(water.geoms, device)
        self.bodies = _index(water.bodies, device)
        self.roots = _index(water._tree_roots, device)
        self.body_ids = _index(water.body_ids, device)
        self.slot = _index([list(water.body_ids).index(b) for b in water.bodies], device)
        self.centre = torch.tensor([r[0] for r in rows], **f)  # (G, 3)
        self.k1, self.k2 = _index(water._k1, device), _index(water._k2, device)
        self.each = torch.arange(len(rows), device=device)
        self.e1, self.e2 = torch.tensor(water._e1, **f), torch.tensor(water._e2, **f)
        self.area = torch.tensor(water.area, **f)
        pushed = [i for i, r in enumerate(rows) if r[7] is not None]
        table = [rows[i][7] for i in pushed]  # (joint, dof, qpos, unlimited, low, high, inertia)
        self.pushed = _index(pushed, device)
        self.joint, self.dof, self.qadr = (_index([t[k] for t in table], device) for k in range(3))
        self.free = torch.tensor([t[3] for t in table], dtype=torch.bool, device=device)
        self.low, self.high, self.inertia = (
            torch.tensor([t[k] for t in table], **f) for k in (4, 5, 6)
        )

    def forces(self, sim: Simulation, level: torch.Tensor) -> torch.Tensor:
        r = sim.field("geom_xmat")[:, self.geoms].flatten(2)  # (N, G, 9)
        p = sim.field("geom_xpos")[:, self.geoms] + torch.einsum(
            "ngij,gj->ngi", r.unflatten(2, (3, 3)), self.centre
        )
        px, py, pz = p.unbind(2)
        g = self.each
        ux, uz, wx, wz = (
            r[:, g, self.k1],
            r[:, g, self.k1 + 6],
            r[:, g, self.k2],
            r[:, g, self.k2 + 6],
        )
        half_z = uz.abs() * self.e1 + wz.abs() * self.e2
        bottom = pz - half_z
        level = level[:, None]
        wet = bottom < level
        frac = ((level - bottom) / (2 * half_z + 1e-9)).clamp(max=1.0)
        w_x, w_y, w_z, v_x, _, v_z = sim.field("cvel")[:, self.bodies].unbind(2)
        cx, cy, cz = sim.field("subtree_com")[:, self.roots].unbind(2)
        ax, _, az = sim.field("xipos")[:, self.bodies].unbind(2)
        buoyancy = self.density * self.area * frac * self.gravity
        ry = py - cy
        # the four edges of each rectangle: outward normal, half extent to it, its length
        nx = torch.stack((ux, -ux, wx, -wx), dim=2)
        nz = torch.stack((uz, -uz, wz, -wz), dim=2)
        offset = torch.stack((self.e1, self.e1, self.e2, self.e2), dim=1)  # (G, 4)
        length = torch.stack((self.e2, self.e2, self.e1, self.e1), dim=1) * 2
        mx, mz = px[..., None] + offset * nx, pz[..., None] + offset * nz
        vx = v_x[..., None] + w_y[..., None] * (mz - cz[..., None]) - (w_z * ry)[..., None]
        vz = v_z[..., None] + (w_x * ry)[..., None] - w_y[..., None] * (mx - cx[..., None])
        speed2 = vx * vx + vz * vz
        inv = speed2.clamp(min=1e-18).rsqrt()
        n_v = (nx * vx + nz * vz) * inv
        leading = (speed2 >= 1e-18) & (n_v > 0.0)
        t_v = (nx * vz - nz * vx) * inv
        base = length * self.density * speed2 * frac[..., None]
        drag = (DRAG_MOD * n_v * base).clamp(max=MAX_DRAG)
        lift = (LIFT_MOD * n_v * t_v * base).clamp(max=MAX_LIFT)
        fx = torch.where(leading, (-drag * vx - lift * vz) * inv, 0.0)
        fz = torch.where(leading, (-drag * vz + lift * vx) * inv, 0.0)
        torque = (mz - az[..., None]) * fx - (mx - ax[..., None]) * fz
        out = torch.stack(
            (fx.sum(2), buoyancy + fz.sum(2), torque.sum(2) - (px - ax) * buoyancy), 2
        )
        if len(self.pushed):
            out = out.index_add(1, self.pushed, self._push(sim, nx, nz, length, frac, ax, az))
        out = out * wet[..., None]
        per_body = torch.zeros((len(r), len(self.body_ids), 3), device=r.device, dtype=r.dtype)
        return per_body.index_add_(1, self.slot, out)

    def _push(self, sim, nx, nz, length, frac, ax, az) -> torch.Tensor:
        """(N, pushed geoms, 3) swimming thrust at the motors' joint anchors."""
        g = self.pushed
        q = sim.field("qpos")[:, self.qadr]
        active = self.free | ((self.low < q) & (q < self.high))
        sign = -sim.field("xaxis")[:, self.joint, 1]
        tau = sim.field("qfrc_actuator")[:, self.dof] * sign
        omega = sim.field("qvel")[:, self.dof] * sign
        anchor = sim.field("xanchor")[:, self.joint]
        ax, az = ax[:, g], az[:, g]
        f_x, f_z = -tau * (az - anchor[..., 2]), tau * (ax - anchor[..., 0])
        gain = PUSH_MOD * self.density * (tau + self.inertia * omega) ** 2
        n_f = nx[:, g] * f_x[..., None] + nz[:, g] * f_z[..., None]
        magnitude = torch.where(n_f > 0.0, n_f * length[g] * gain[..., None], 0.0)
        push_x = (-magnitude * f_x[..., None]).clamp(-self.clip, self.clip).sum(2)
        push_z = (-magnitude * f_z[..., None]).clamp(-self.clip, self.clip).sum(2)
        push_x, push_z = push_x * frac[:, g] * active, push_z * frac[:, g] * active
        torque = (anchor[..., 2] - az) * push_x - (anchor[..., 0] - ax) * push_z
        return torch.stack((push_x, push_z, torque), dim=2)
