"""3D Terrain's fields for many worlds at once, built on the simulation's device.

`Terrain3DGenerator.heights` builds one world's field with numpy and a Python loop over its rows
of blocks (about 0.13 ms a world); a GPU simulation resets over a hundred worlds per step at
16,384 worlds, so that loop, on the host while the GPU waits, would take as long as the step.
Here the same field is built for all resetting worlds in a few tensor operations: hills and the
alternating cross slope along x, the roughness lattice interpolated bilinearly, and the rows of
blocks (row k at start + 1 m + k (0.5 m + spacing), height max(0, N(block_height, 0.05)), its
centre uniform across the field), each covering the grid points the CPU generator's `_points`
picks (same tolerances). Fields equal `Terrain3DGenerator.heights` given the same draws
(tests/test_tensor_terrain3d.py); the draws come from a torch generator on the device, another
stream than a single env's.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from acl3d.terrain.terrain3d import (
    BLOCK_LENGTH,
    BLOCK_NOISE,
    FIRST_BLOCK,
    HILL_WAVELENGTH,
    PARAMETERS,
    TWIST_WAVELENGTH,
    Terrain3DGenerator,
)

F64 = torch.float64
CHUNK = 2048  # worlds built at once: a field is ~10k points, its temporaries a few times that


class TensorTerrain3D:
    """3D Terrain's fields for N worlds (see the module docstring).

    Args:
        generator: the env's CPU generator (its grid, start pad and roughness lattice).
        names: the task space's parameter names (their order in a task vector); parameters
            left out take their defaults, as the CPU generator does.
        device: where the fields are built.
    """

    DRAWS = ("sign", "lattice", "normal", "uniform")  # the keys of `draws`, in draw order

    def __init__(self, generator: Terrain3DGenerator, names: tuple[str, ...], device):
        g, self.device = generator.grid, torch.device(device)
        self.names = tuple(names)
        as_tensor = lambda a: torch.as_tensor(a, dtype=F64, device=self.device)  # noqa: E731
        self.x_min, self.cell, self.ncol = g.x_min, g.cell, g.ncol
        self.half_width, self.row_cell, self.nrow = g.half_width, g.row_cell, g.nrow
        self.y = as_tensor(g.y)[:, None]
        self.start, self.end_x = generator.start_pad + FIRST_BLOCK, generator.end_x
        along = torch.as_tensor(generator._along, dtype=F64, device=self.device)
        self.hill_shape = 1.0 - torch.cos(2 * math.pi * along / HILL_WAVELENGTH)
        self.twist_shape = torch.sin(2 * math.pi * along / TWIST_WAVELENGTH)
        self.lattice_shape = generator._lattice_shape
        (iy, ix), (wy, wx) = generator._rough_index, generator._rough_w
        # the four lattice corners of every field point, as flat indices into a lattice
        width = self.lattice_shape[1]
        corners = [(iy + dy) * width + ix + dx for dy in (0, 1) for dx in (0, 1)]
        self.corners = torch.as_tensor(np.stack(corners).reshape(4, -1), device=self.device)
        self.wy, self.wx = as_tensor(wy), as_tensor(wx)
        self.fade = as_tensor(generator._rough_fade)
        # rows of blocks at the smallest spacing (0): the most a field can hold
        self.max_blocks = max(1, math.ceil((self.end_x - self.start) / BLOCK_LENGTH) + 1)
        self.columns = torch.arange(g.ncol, device=self.device)
        self.rows = torch.arange(g.nrow, device=self.device)[:, None]

    def draws(self, n: int, generator: torch.Generator) -> dict[str, torch.Tensor]:
        """The random numbers of n fields: the twist's sign, the roughness lattice, and per row
        of blocks a standard normal (height) and a uniform (centre)."""
        f = {"generator": generator, "device": self.device, "dtype": F64}
        return {
            "sign": torch.rand(n, **f),
            "lattice": torch.rand((n, *self.lattice_shape), **f) * 2.0 - 1.0,
            "normal": torch.randn((n, self.max_blocks), **f),
            "uniform": torch.rand((n, self.max_blocks), **f),
        }

    def heights(self, tasks: torch.Tensor, draws: dict[str, torch.Tensor]) -> torch.Tensor:
        """(n, nrow, ncol) float64 heights in metres for tasks (n, d) (float64, in `names`
        order) and `draws(n)`."""
        parts = [
            self._heights(tasks[lo : lo + CHUNK], {k: v[lo : lo + CHUNK] for k, v in draws.items()})
            for lo in range(0, len(tasks), CHUNK)
        ]
        return torch.cat(parts)

    def _parameter(self, tasks: torch.Tensor, name: str) -> torch.Tensor:
        if name in self.names:
            return tasks[:, self.names.index(name)]
        return torch.full_like(tasks[:, 0], float(PARAMETERS[name].default[0]))

    def _heights(self, tasks: torch.Tensor, draws: dict[str, torch.Tensor]) -> torch.Tensor:
        p = {name: self._parameter(tasks, name) for name in PARAMETERS}
        hill = torch.tan(torch.deg2rad(p["hill_slope"])) * HILL_WAVELENGTH / (2 * math.pi)
        sign = torch.where(draws["sign"] < 0.5, 1.0, -1.0)
        roll = sign * torch.tan(torch.deg2rad(p["cross_slope"]))
        ground = hill[:, None] * self.hill_shape
        twist = roll[:, None] * self.twist_shape
        h = ground[:, None, :] + self.y * twist[:, None, :]
        rough = p["roughness"][:, None, None]
        h = torch.where(rough > 0.0, h + rough * self.fade * self._bilinear(draws["lattice"]), h)
        return h + self._blocks(p, draws)

    def _bilinear(self, lattice: torch.Tensor) -> torch.Tensor:
        flat, shape = lattice.flatten(1), (len(lattice), self.nrow, self.ncol)
        a, b, c, d = (flat[:, corner].view(shape) for corner in self.corners)
        wy, wx = self.wy, self.wx
        return (a * (1.0 - wx) + b * wx) * (1.0 - wy) + (c * (1.0 - wx) + d * wx) * wy

    def _blocks(self, p: dict[str, torch.Tensor], draws: dict[str, torch.Tensor]) -> torch.Tensor:
        """(n, nrow, ncol) the rows of blocks' heights where they stand, 0 elsewhere."""
        n = len(p["block_height"])
        width = p["block_width"] * 2 * self.half_width
        built = (width > 0.0) & (p["block_height"] > 0.0)
        # row k starts where the CPU loop's x is after k steps of 0.5 m + spacing
        step = (BLOCK_LENGTH + p["block_spacing"])[:, None].expand(-1, self.max_blocks - 1)
        x0 = torch.cat((torch.full((n, 1), self.start, dtype=F64, device=self.device), step), 1)
        x0 = x0.cumsum(1)
        height = (p["block_height"][:, None] + BLOCK_NOISE * draws["normal"]).clamp(min=0.0)
        height = torch.where((x0 < self.end_x) & built[:, None], height, 0.0)
        lo_c, hi_c = -self.half_width + width / 2, self.half_width - width / 2
        centre = lo_c[:, None] + (hi_c - lo_c)[:, None] * draws["uniform"]
        lo, hi = centre - width[:, None] / 2, centre + width[:, None] / 2
        first = ((x0 - self.x_min) / self.cell - 1e-9).ceil().clamp(min=0).long()
        stop = ((x0 + BLOCK_LENGTH - self.x_min) / self.cell - 1e-9).ceil().long()
        row0 = ((lo + self.half_width) / self.row_cell - 1e-9).ceil().clamp(min=0).long()
        row1 = ((hi + self.half_width) / self.row_cell + 1e-9).floor().long() + 1
        # the row of blocks whose first column is the last at or before each column, and the
        # one before it (neighbours share no column, but heights add up if they ever did)
        cols = self.columns.expand(n, -1).contiguous()
        idx = torch.searchsorted(first, cols, right=True) - 1
        out = torch.zeros((n, self.nrow, self.ncol), dtype=F64, device=self.device)
        for shift in (0, 1):
            j = idx - shift
            valid = j >= 0
            j = j.clamp(min=0)
            along = valid & (cols >= first.gather(1, j)) & (cols < stop.gather(1, j))
            across = (self.rows >= row0.gather(1, j)[:, None]) & (
                self.rows < row1.gather(1, j)[:, None]
            )
            out = out + torch.where(along[:, None, :] & across, height.gather(1, j)[:, None], 0.0)
        return out
