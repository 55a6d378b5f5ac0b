"""What differs between the worlds of one simulation, and the interface every backend implements.

mjlab's pattern: one model, N worlds, and the fields a world may change declared up front, so a
backend knows which model arrays it must give a leading world dimension (MuJoCo Warp) or which
quantities each world's model copy owns (MuJoCo's batch on the CPU).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch

MAX_WORLDS = 1 << 20


@dataclass(frozen=True)
class WorldFields:
    """The per-world quantities of a family's model.

    terrain_hfields: names of the heightfield assets each world rewrites at its resets (its own
        terrain). On MuJoCo Warp each world gets its own copy of the asset, routed to it through
        the batched `geom_dataid`; `terrain_geoms` are the geoms that use them, in order.
    force_caps: every world caps its actuators' forces on its own (`actuator_forcerange`: the
        velocity servos' torque cap is |a| * torque, written each step).
    weld_anchors: every world places its weld equalities' anchors on its own (`eq_data`: where
        a climber's hand grabbed). Which welds are on (`eq_active`) and the applied forces
        (`xfrc_applied`: Parkour's water) are per world in any case: they are state, not model.
    """

    terrain_hfields: tuple[str, ...] = ()
    terrain_geoms: tuple[str, ...] = ()
    force_caps: bool = False
    weld_anchors: bool = False

    def __post_init__(self):
        if len(self.terrain_hfields) != len(self.terrain_geoms):
            raise ValueError(
                f"terrain_hfields={self.terrain_hfields} and terrain_geoms={self.terrain_geoms}: "
                "one geom per heightfield"
            )


class Simulation(Protocol):
    """N worlds of one model stepped together; state read and written as live torch tensors.

    Tensors live on `device`; `field(name)` views are live (a step updates them in place) and
    keep their identity across steps, so callers may hold them. As after `mj_step`, derived
    fields (xpos, xmat, cvel, sensordata) describe the state the last substep started from.
    """

    nworld: int
    device: torch.device
    dtype: torch.dtype

    def field(self, name: str) -> torch.Tensor:
        """Live (N, ...) tensor of a Data field: qpos, qvel, ctrl, xpos, xmat, cvel, cdof_dot,
        sensordata;
        for forces and constraints also geom_xpos, geom_xmat, xipos, subtree_com, xaxis,
        xanchor, qfrc_actuator, and the writable xfrc_applied and eq_active."""
        ...

    def weld_anchors(self) -> torch.Tensor:
        """Live (N, neq, 12) per-world equality data, MuJoCo's 11 numbers padded to 12 (declared
        with `weld_anchors`)."""
        ...

    def force_caps(self) -> torch.Tensor:
        """Live (N, nu, 2) per-world actuator force ranges (declared with `force_caps`)."""
        ...

    def set_force_caps(self, index: torch.Tensor, ranges: torch.Tensor) -> None:
        """Actuators `index` of world i get the force ranges `ranges[i]` ((N, len(index), 2)),
        as the CPU backends do (`acl3d.envs.physics`)."""
        ...

    def terrain(self, hfield: str) -> torch.Tensor:
        """Live (N, nrow, ncol) per-world elevation data (0..1) of a declared terrain heightfield."""
        ...

    def reset_worlds(self, ids: torch.Tensor, qpos: torch.Tensor, qvel: torch.Tensor) -> None:
        """Clear worlds `ids` ((k,) indices on the device) and put them in state (qpos, qvel)
        ((k, nq), (k, nv)), with no applied forces and their equalities as compiled; other worlds
        are untouched. Their derived fields are recomputed by
        the next `step` (or `forward`), so a reset costs no physics."""
        ...

    def forward(self) -> None:
        """Recompute every world's derived fields from its state (MuJoCo's `mj_forward`)."""
        ...

    def step(self) -> None:
        """`nstep` substeps of every world."""
        ...
