"""MuJoCo Warp: N worlds of one model on a CUDA GPU (or Warp's CPU device, for tests).

The model goes to the device once (`mujoco_warp.put_model`); the fields `WorldFields` declares get
a leading world dimension there:

* force caps: `actuator_forcerange` batched (N, nu, 2), written by the rules before each step;
* weld anchors: `eq_data` batched (N, neq, 12), written by the rules (Parkour's grasps; which
  welds are on, `eq_active`, and the applied forces, `xfrc_applied`, are Data: per world anyway);
* terrain: each declared heightfield asset is copied once per world at the end of
  `hfield_data` (same rows, columns and size: only the address differs), and the batched
  `geom_dataid` (N, ngeom) routes world i's terrain geom to its own copy. This is the route MuJoCo
  Warp's collision reads per world; the alternative, one large tiled heightfield with a tile per
  world, would move every world's body to its own tile and change what the rules read (x), so it
  was not taken (docs/architecture.md compares the two).

Every array is read and written through zero-copy torch views (`warp.to_torch`). The `nstep`
substeps of a step and a `forward` are each captured once as a graph and replayed
(a CUDA graph on a GPU; on Warp's CPU device a recorded launch list, 6.6x faster than launching
each kernel from Python). On a GPU, Warp's stream and torch's current stream are ordered with
events, so torch writes (controls, caps, reset states) are seen by the graph and its results by
torch, with no host sync.
"""

from __future__ import annotations

import importlib

import mujoco
import numpy as np
import torch

from acl3d import validation
from acl3d.extras import optional_dependency
from acl3d.sim.worlds import MAX_WORLDS, WorldFields

MAX_CONSTRAINT_ROWS = 8192  # MuJoCo Warp's largest estimate; more is memory for nothing here
MAX_CONTACT_SLOTS = 8192  # the same bound for the contact slots

_FIELDS = (
    *("qpos", "qvel", "ctrl", "xpos", "xmat", "cvel", "cdof_dot", "sensordata", "qacc_warmstart"),
    "time",
)
# what forces and constraints computed on torch read (Parkour's water and grasps) and write
_FORCE_FIELDS = (
    *("geom_xpos", "geom_xmat", "xipos", "subtree_com", "xaxis", "xanchor", "qfrc_actuator"),
    *("xfrc_applied", "eq_active"),
)


def import_warp():
    """(warp, mujoco_warp), or an error naming the extra that installs them."""
    with optional_dependency("the MuJoCo Warp backend (many worlds on a GPU)"):
        warp = importlib.import_module("warp")
        mjw = importlib.import_module("mujoco_warp")
    warp.config.log_level = warp.LOG_WARNING  # not a line per kernel module loaded
    return warp, mjw


def warp_device_name(device: torch.device) -> str:
    """Warp's name of a torch device ("cuda:0", "cpu")."""
    if device.type == "cuda":
        return f"cuda:{device.index if device.index is not None else torch.cuda.current_device()}"
    if device.type == "cpu":
        return "cpu"
    raise ValueError(f"device={device}; valid: a CUDA device or cpu")


class WarpSimulation:
    """N worlds of `model` on MuJoCo Warp (see the module docstring).

    Args:
        model: the family's compiled model (its heightfields hold world 0's initial terrain).
        nworld: number of worlds, in [1, 2**20].
        nstep: substeps per `step()` (the env's frame_skip).
        fields: the per-world quantities.
        device: a torch device: "cuda" (or "cuda:k") or "cpu" (Warp's CPU device).
        constraint_rows: constraint rows (contacts, limits, welds) reserved per world, MuJoCo
            Warp's `njmax`; None: its estimate from the model. The solver's passes cost in
            proportion to it, and a world that needs more drops the rest (MuJoCo Warp prints
            "nefc overflow"; `constraint_overflows()` says which worlds did).
        contact_slots: contact slots reserved per world, MuJoCo Warp's `nconmax`; None: its
            estimate from the model. The worlds share one pool of N x this for the broadphase's
            candidate pairs and the contacts; kernels over the pool cost in proportion to it,
            and when a step's pairs or contacts exceed it the rest are dropped (MuJoCo Warp
            prints "broadphase overflow" or "narrowphase overflow"; `contact_overflows()`).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        nworld: int,
        nstep: int,
        fields: WorldFields,
        device="cuda",
        constraint_rows: int | None = None,
        contact_slots: int | None = None,
    ):
        if not 1 <= nworld <= MAX_WORLDS:
            raise ValueError(f"nworld={nworld}; valid: [1, {MAX_WORLDS}]")
        if constraint_rows is not None:
            validation.integer("constraint_rows", constraint_rows, 1, MAX_CONSTRAINT_ROWS)
        if contact_slots is not None:
            validation.integer("contact_slots", contact_slots, 1, MAX_CONTACT_SLOTS)
        self._wp, self._mjw = import_warp()
        wp, mjw = self._wp, self._mjw
        self.device = torch.device(device)
        self.dtype = torch.float32
        self.nworld, self.nstep, self.fields = nworld, nstep, fields
        self._wp_device = wp.get_device(warp_device_name(self.device))
        batch = {}
        if fields.force_caps:
            batch["actuator_forcerange"] = nworld
        if fields.terrain_hfields:
            batch["geom_dataid"] = nworld
        if fields.weld_anchors:
            batch["eq_data"] = nworld
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        with wp.ScopedDevice(self._wp_device):
            self.m = mjw.put_model(model, batch_sizes=batch)
            # a foot on a stump meets more heightfield prisms than MuJoCo Warp keeps contacts for
            # (50 per pair): the extra ones are dropped, a documented difference
            # (docs/architecture.md), not a message printed at every step
            self.m.opt.warn_overflow &= ~int(mjw.OverflowType.HFIELD)
            self.d = mjw.put_data(
                model, data, nworld=nworld, njmax=constraint_rows, nconmax=contact_slots
            )
            self._terrain = self._route_terrain(model, fields)
        self._views = {name: wp.to_torch(getattr(self.d, name)) for name in _FIELDS + _FORCE_FIELDS}
        self._overflow = wp.to_torch(self.d.overflow)
        self._caps = wp.to_torch(self.m.actuator_forcerange) if fields.force_caps else None
        self._anchors = wp.to_torch(self.m.eq_data) if fields.weld_anchors else None
        self._eq_active0 = torch.as_tensor(model.eq_active0.astype(bool), device=self.device)
        self._graphs: dict[str, object] = {}

    # ------------------------------------------------------------------ per-world terrain
    def _route_terrain(self, model: mujoco.MjModel, fields: WorldFields) -> dict[str, torch.Tensor]:
        """Give each world its own copy of every declared heightfield (see the module docstring)."""
        wp, m, n = self._wp, self.m, self.nworld
        if not fields.terrain_hfields:
            return {}
        sizes = [model.hfield_size.copy()]
        nrows, ncols = [model.hfield_nrow.copy()], [model.hfield_ncol.copy()]
        adrs, data = [model.hfield_adr.copy()], [model.hfield_data.astype(np.float32)]
        dataid = np.tile(model.geom_dataid, (n, 1)).astype(np.int32)
        next_id, next_adr = model.nhfield, model.nhfielddata
        spans = {}
        for name, geom in zip(fields.terrain_hfields, fields.terrain_geoms):
            h = model.hfield(name).id
            nrow, ncol = int(model.hfield_nrow[h]), int(model.hfield_ncol[h])
            size = nrow * ncol
            sizes.append(np.tile(model.hfield_size[h], (n, 1)))
            nrows.append(np.full(n, nrow))
            ncols.append(np.full(n, ncol))
            adrs.append(next_adr + size * np.arange(n))
            own = model.hfield_data[model.hfield_adr[h] : model.hfield_adr[h] + size]
            data.append(np.tile(own.astype(np.float32), n))
            dataid[:, model.geom(geom).id] = next_id + np.arange(n)
            spans[name] = (next_adr, nrow, ncol)
            next_id, next_adr = next_id + n, next_adr + n * size
        m.hfield_size = wp.array(np.concatenate(sizes).astype(np.float32), dtype=wp.vec4)
        m.hfield_nrow = wp.array(np.concatenate(nrows).astype(np.int32), dtype=int)
        m.hfield_ncol = wp.array(np.concatenate(ncols).astype(np.int32), dtype=int)
        m.hfield_adr = wp.array(np.concatenate(adrs).astype(np.int32), dtype=int)
        m.hfield_data = wp.array(np.concatenate(data), dtype=float)
        m.geom_dataid = wp.array(dataid, dtype=int)
        m.nhfield, m.nhfielddata = next_id, next_adr
        flat = wp.to_torch(m.hfield_data)
        return {
            name: flat[adr : adr + n * nrow * ncol].view(n, nrow, ncol)
            for name, (adr, nrow, ncol) in spans.items()
        }

    # ------------------------------------------------------------------ the Simulation protocol
    def field(self, name: str) -> torch.Tensor:
        """Live (N, ...) view: qpos, qvel, ctrl, xpos (N, nbody, 3), xmat (N, nbody, 3, 3),
        cvel (N, nbody, 6), cdof_dot (N, nv, 6), sensordata, qacc_warmstart, time (N,); geom_xpos, geom_xmat, xipos,
        subtree_com, xaxis, xanchor, qfrc_actuator, xfrc_applied (N, nbody, 6), eq_active
        (N, neq) bool."""
        return self._views[name]

    def weld_anchors(self) -> torch.Tensor:
        if self._anchors is None:
            raise ValueError("weld anchors are not per-world fields of this simulation")
        return self._anchors

    def force_caps(self) -> torch.Tensor:
        if self._caps is None:
            raise ValueError("force caps are not per-world fields of this simulation")
        return self._caps

    def set_force_caps(self, index: torch.Tensor, ranges: torch.Tensor) -> None:
        self.force_caps()[:, index] = ranges

    def terrain(self, hfield: str) -> torch.Tensor:
        return self._terrain[hfield]

    @property
    def constraint_rows(self) -> int:
        """Constraint rows reserved per world (`njmax`)."""
        return int(self.d.njmax)

    def constraint_overflows(self) -> torch.Tensor:
        """(N,) bool: the worlds that needed more constraint rows than reserved since they were
        made (each dropped the rows beyond `constraint_rows` in those steps)."""
        flag = int(self._mjw.OverflowType.NEFC)
        return (self._overflow & flag) != 0

    @property
    def contact_slots(self) -> int:
        """Contact slots reserved per world (`nconmax`: the shared pool over N)."""
        return int(self.d.naconmax) // self.nworld

    def contact_overflows(self) -> bool:
        """Whether a step since the worlds were made had more candidate pairs or contacts than
        the shared pool holds (some were dropped; MuJoCo Warp flags every world then)."""
        kinds = self._mjw.OverflowType
        flag = int(kinds.BROADPHASE) | int(kinds.NARROWPHASE)
        return bool(((self._overflow & flag) != 0).any())

    def reset_worlds(self, ids: torch.Tensor, qpos: torch.Tensor, qvel: torch.Tensor) -> None:
        v = self._views
        v["qpos"].index_copy_(0, ids, qpos.to(self.dtype))
        v["qvel"].index_copy_(0, ids, qvel.to(self.dtype))
        for name in ("qacc_warmstart", "ctrl", "xfrc_applied"):
            v[name].index_fill_(0, ids, 0.0)
        v["time"].index_fill_(0, ids, 0.0)
        v["eq_active"][ids] = self._eq_active0

    def forward(self) -> None:
        self._run("forward", lambda: self._mjw.forward(self.m, self.d))

    def step(self) -> None:
        def substeps():
            for _ in range(self.nstep):
                self._mjw.step(self.m, self.d)

        self._run("step", substeps)

    # ------------------------------------------------------------------ launches
    def _run(self, name: str, launch) -> None:
        """Run `launch` (Warp kernels) as a graph captured at its first call (CUDA graphs on a
        GPU, Warp's replayed launch lists on the CPU), in order with torch's work on the GPU."""
        wp = self._wp
        cuda = self.device.type == "cuda"
        if cuda:
            torch_stream = wp.stream_from_torch(torch.cuda.current_stream(self.device))
            stream = wp.get_stream(self._wp_device)
            stream.wait_stream(torch_stream)
        graph = self._graphs.get(name)
        if graph is None:  # the first call runs eagerly (compiling the kernels), then records
            with wp.ScopedDevice(self._wp_device):
                launch()
                with wp.ScopedCapture(self._wp_device) as capture:
                    launch()
            self._graphs[name] = capture.graph
        else:
            wp.capture_launch(graph, stream=stream if cuda else None)
        if cuda:
            torch_stream.wait_stream(stream)
