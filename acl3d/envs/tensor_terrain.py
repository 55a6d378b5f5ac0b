"""Stump Tracks' height lines for many worlds at once, drawn on the simulation's device.

`TrackGenerator.heights` builds one world's track in a Python loop over its obstacles (0.1-1.2 ms
on the CPU); a GPU simulation resets hundreds of worlds per step, so that loop would bound it.
For the tasks of plain stumps (stump_height and obstacle_spacing: Stump Tracks' task space), the
track is regular enough to build for all resetting worlds in a few tensor operations: stump k
starts at x0 + k (w + spacing) with w = 1 TS and height max(0.05, N(stump_height, 0.1)) TS, and
covers the grid columns whose x lies in [x_k, x_k + w] (`tracks._columns`, same tolerances).
Heights equal `TrackGenerator.heights` given the same normal draws (tests/test_many_worlds.py);
the draws come from a torch generator on the device, another stream than a single env's.
Other track kinds (hexagons, rotated stumps, sequences, widths) stay on the CPU generator.
"""

from __future__ import annotations

import math

import torch

from acl3d.terrain.tracks import (
    MAX_TERRAIN_HEIGHT,
    MIN_OBSTACLE,
    NOISE_STD,
    TERRAIN_LENGTH,
    TERRAIN_STEP,
    TRACK_PARAMETERS,
    TrackGrid,
)

PLAIN_STUMPS = ("stump_height", "obstacle_spacing")


class TensorStumpTracks:
    """Height lines of plain stumps for N worlds (see the module docstring).

    Args:
        grid: the track's columns.
        names: the task space's parameter names (their order in a task vector).
        start_pad: the start pad in TS (the body's).
        device: where the heights are built.
    """

    def __init__(self, grid: TrackGrid, names: tuple[str, ...], start_pad: int, device):
        self.supported = "stump_height" in names and set(names) <= set(PLAIN_STUMPS)
        self.names, self.device = tuple(names), torch.device(device)
        self.x_min, self.cell, self.ncol = grid.x_min, grid.cell, grid.ncol
        self.start = start_pad * TERRAIN_STEP
        self.end = TERRAIN_LENGTH * TERRAIN_STEP
        self.max_stumps = math.ceil((self.end - self.start) / TERRAIN_STEP) + 1
        self.columns = torch.arange(grid.ncol, device=self.device)

    def draws(self, n: int, generator: torch.Generator) -> torch.Tensor:
        """(n, max_stumps) standard normal draws, one per possible stump."""
        return torch.randn(
            (n, self.max_stumps), generator=generator, device=self.device, dtype=torch.float64
        )

    def heights(self, tasks: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """(n, ncol) float64 heights for tasks (n, d) (float64, in `names` order) and normals
        (n, max_stumps) from `draws`."""
        height_mean = tasks[:, self.names.index("stump_height")]
        if "obstacle_spacing" in self.names:
            spacing = tasks[:, self.names.index("obstacle_spacing")]
        else:  # the parameter's default when the task space leaves it out
            default = TRACK_PARAMETERS["obstacle_spacing"].default[0]
            spacing = torch.full_like(height_mean, float(default))
        k = torch.arange(self.max_stumps, device=self.device, dtype=torch.float64)
        x0 = self.start + k * (TERRAIN_STEP + spacing[:, None])  # (n, K) stump starts
        x1 = x0 + TERRAIN_STEP
        h = (height_mean[:, None] + NOISE_STD * normals).clamp(min=MIN_OBSTACLE) * TERRAIN_STEP
        h = torch.where(x0 < self.end, h, 0.0)  # stumps past the course's end are not built
        first = ((x0 - self.x_min) / self.cell - 1e-9).ceil().clamp(min=0).long()
        last = ((x1 - self.x_min) / self.cell + 1e-9).floor().clamp(max=self.ncol - 1).long()
        # the stump whose first column is the last at or before each column, and the one before
        # (adjacent stumps share their border column when the spacing is 0: the higher wins)
        cols = self.columns.expand(len(tasks), -1).contiguous()
        idx = torch.searchsorted(first, cols, right=True) - 1
        out = torch.zeros(cols.shape, device=self.device, dtype=torch.float64)
        for shift in (0, 1):
            j = idx - shift
            valid = j >= 0
            j = j.clamp(min=0)
            covered = valid & (cols >= first.gather(1, j)) & (cols <= last.gather(1, j))
            out = torch.maximum(out, torch.where(covered, h.gather(1, j), 0.0))
        return out.clamp(max=MAX_TERRAIN_HEIGHT)
