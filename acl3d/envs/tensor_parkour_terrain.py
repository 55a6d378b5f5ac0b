"""Parkour's terrain for many worlds at once, built on the simulation's device.

`ParkourGenerator.generate` runs the frozen CPPN (200 points, four 64-unit layers) and places the
creepers for one world in numpy; `ParkourWorlds` then interpolates its lines onto the grid and
packs them into the world's record, one world at a time on the host while the GPU waits. Here
the same records are built for all resetting worlds in a few tensor operations: the CPPN as
batched matrix products, the start pad and ceiling clip, the water level, the creepers on every
`period`-th knot (one normal draw each, in order), the climbers' shift (each climber's world is
moved so that its start-pad ceiling sits on the highest hand), and the lines' linear
interpolation onto the grid's columns (uniform knots: an index and a weight per column, as
`np.interp` with its end values held). Records equal the CPU path's given the same draws
(tests/test_tensor_parkour_terrain.py); the draws come from a torch generator on the device.
"""

from __future__ import annotations

import numpy as np
import torch

from acl3d.envs.parkour_arena import CEILING_RANGE, GROUND_RANGE
from acl3d.task_space import TaskSpace
from acl3d.terrain.parkour import (
    CEILING_CLIP_OFFSET,
    CEILING_OFFSET,
    CPPN_POINTS,
    CREEPER_NOISE_STD,
    GROUND_LIMIT,
    MIN_CREEPER_SIZE,
    MIN_CREEPER_SPACING,
    MIN_WATER_LEVEL,
    TERRAIN_HEIGHT,
    ParkourGenerator,
    cppn_weights,
)
from acl3d.terrain.tracks import TERRAIN_STEP

F64 = torch.float64


class TensorParkourTerrain:
    """Parkour records (`ParkourRecord` layout) for N worlds (see the module docstring).

    Args:
        generator: the env's CPU generator (CPPN seed, start pad, knots).
        space: the Parkour task space (its columns of each parameter).
        record: the rules' record layout (lines, water, creeper pool).
        grid_x: x of the grid's columns the lines are read on.
        hand_top: climbers: the highest hand's top with the body placed (None: walkers).
        device: where the records are built.
    """

    def __init__(self, generator: ParkourGenerator, space: TaskSpace, record, grid_x,
                 hand_top: float | None, device):  # fmt: skip
        self.device, self.record, self.hand_top = torch.device(device), record, hand_top
        f = {"dtype": F64, "device": self.device}
        self.weights = [torch.tensor(np.array(w), **f) for w in cppn_weights(generator.seed)]
        self.x01 = torch.as_tensor(np.linspace(0.0, 1.0, CPPN_POINTS), **f)
        self.start_pad, self.nb_points = generator.start_pad, generator.nb_points
        self.knots_x = torch.as_tensor(generator.x, **f)
        self.columns = {name: space.slice(name) for name in space.names}
        self.pool = record.slices["creepers"].stop - record.slices["creepers"].start
        self.pool //= 4
        # linear interpolation from the knots (i * TS) onto the grid, end values held
        u = np.asarray(grid_x, dtype=np.float64) / TERRAIN_STEP
        j = np.clip(np.floor(u), 0, self.nb_points - 2).astype(np.int64)
        self.left = torch.as_tensor(j, device=self.device)
        self.weight = torch.as_tensor(np.clip(u - j, 0.0, 1.0), **f)

    def draws(self, n: int, generator: torch.Generator) -> torch.Tensor:
        """(n, pool) standard normals: one per possible creeper, in knot order."""
        return torch.randn((n, self.pool), generator=generator, device=self.device, dtype=F64)

    def _column(self, tasks: torch.Tensor, name: str) -> torch.Tensor:
        return tasks[:, self.columns[name]]

    def lines(self, tasks: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(ground, ceiling) (n, knots) in metres, as `ParkourGenerator.height_lines`."""
        h1, h2, h3, h4, out = self.weights
        v = self._column(tasks, "input_vector")
        scale = self._column(tasks, "terrain_cppn_scale")
        rows = torch.cat((self.x01.expand(len(v), -1)[..., None], v[:, None, :].expand(
            -1, CPPN_POINTS, -1)), dim=-1)  # fmt: skip
        zero = torch.zeros((), dtype=F64, device=self.device)
        h = torch.logaddexp(zero, torch.tanh(rows @ h1) @ h2)
        h = torch.logaddexp(zero, torch.tanh(h @ h3) @ h4)
        y = (h @ out) / scale[:, :, None]
        offset, clip = CEILING_OFFSET / scale, CEILING_CLIP_OFFSET / scale
        n, pad = len(tasks), self.start_pad
        ground = torch.zeros((n, self.nb_points), dtype=F64, device=self.device)
        ceiling = offset.expand(-1, self.nb_points).clone()
        ground[:, pad:] = y[..., 0] - y[:, :1, 0]
        ceiling[:, pad:] = y[..., 1] - y[:, :1, 1] + offset
        return ground, torch.maximum(ceiling, ground + clip)

    def records(self, tasks: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """(n, record width) float64 records for tasks (n, d) (float64) and `draws(n)`."""
        ground, ceiling = self.lines(tasks)
        scale = self._column(tasks, "terrain_cppn_scale")[:, 0]
        bottom = GROUND_LIMIT / scale - TERRAIN_HEIGHT
        level = self._column(tasks, "water_level")[:, 0].clamp(min=MIN_WATER_LEVEL)
        water_z = bottom + level * (ceiling.max(dim=1).values - bottom)
        shift = (
            self.hand_top - ceiling[:, 0]
            if self.hand_top is not None
            else torch.zeros_like(water_z)
        )
        record = torch.zeros((len(tasks), self.record.width), dtype=F64, device=self.device)
        rec = self.record
        for name, line, bounds in (("ground", ground, GROUND_RANGE),
                                   ("ceiling", ceiling, CEILING_RANGE)):  # fmt: skip
            shifted = line + shift[:, None]
            a, b = shifted[:, self.left], shifted[:, self.left + 1]
            rec(record, name).copy_((a + self.weight * (b - a)).clamp(*bounds))
        rec(record, "water")[:, 0] = water_z + shift
        rec(record, "creepers").copy_(self._creepers(tasks, ceiling, shift, normals).flatten(1))
        return record

    def _creepers(self, tasks, ceiling, shift, normals) -> torch.Tensor:
        """(n, pool, 4) boxes (centre x, centre z, half width, half height; 0 where unused)."""
        mean = self._column(tasks, "creepers_height")[:, 0]
        width = self._column(tasks, "creepers_width")[:, 0].clamp(min=MIN_CREEPER_SIZE)
        spacing = self._column(tasks, "creepers_spacing")[:, 0].clamp(min=MIN_CREEPER_SPACING)
        period = (spacing / TERRAIN_STEP - 1e-9).ceil().long() + 1
        reach = (width / TERRAIN_STEP).floor().long().clamp(min=1)
        k = torch.arange(self.pool, device=self.device)
        knots = k * period[:, None]  # (n, pool)
        used = (knots < (self.nb_points - reach)[:, None]) & (mean > 0.0)[:, None]
        knots = torch.where(used, knots, 0)
        far = (knots + reach[:, None]).clamp(max=self.nb_points - 1)
        heights = (mean[:, None] + CREEPER_NOISE_STD * normals).clamp(min=MIN_CREEPER_SIZE)
        top = torch.maximum(ceiling.gather(1, knots), ceiling.gather(1, far)) + shift[:, None]
        bottom = top - heights
        x0 = self.knots_x[knots]
        x1 = x0 + width[:, None]
        boxes = torch.stack(
            ((x0 + x1) / 2, (top + bottom) / 2, (x1 - x0) / 2, (top - bottom) / 2), -1
        )
        return torch.where(used[..., None], boxes, 0.0)
