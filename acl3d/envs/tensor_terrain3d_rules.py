"""3D Terrain's rules on torch tensors, with the height scan, for the many-world simulation.

The arithmetic of `Terrain3DRules` (shaping 15 x - 5 |yaw| - 5 |y| (- 5 |pitch|), -100 and the end
of the episode on a critical contact, x < 0 or leaving the field, success on crossing the finish
line) and of `HeightScan` (heights around the body on a forward x lateral grid turned by its
heading, bilinear on the field, edges clamped, relative to the root's height), for all worlds at
once. Constants come from the compiled numpy rules; tests/test_many_worlds.py checks both agree
on the same physics.
"""

from __future__ import annotations

import torch

from acl3d.envs.height_scan import MIN_NORM, HeightScan
from acl3d.envs.tensor_track_rules import TensorTrackRules, torque_use
from acl3d.envs.terrain3d_rules import (
    DRIFT_PENALTY,
    HEADING_PENALTY,
    PROGRESS_GAIN,
    Terrain3DRules,
)
from acl3d.envs.track_rules import ANGLE_PENALTY, FAIL_REWARD
from acl3d.sim.worlds import Simulation


class TensorHeightScan:
    """`HeightScan.read_batch` on tensors: heights (N, rows, cols), origins (N, 3), rotations
    (N, 3, 3) -> (N, nb_rays) terrain height - root height."""

    def __init__(self, scan: HeightScan, device: torch.device, dtype: torch.dtype):
        f = {"device": device, "dtype": dtype}
        self.nb_rays, self.shape = scan.nb_rays, tuple(scan._shape)
        self.cos_part = torch.as_tensor(scan._cos_part).to(**f)  # (2, P): (row, col) offsets
        self.sin_part = torch.as_tensor(scan._sin_part).to(**f)
        self.inv_cell = torch.as_tensor(scan._inv_cell[:, 0]).to(**f)  # (2,)
        self.min = torch.as_tensor(scan._min).to(**f)  # (y_min, x_min)

    def empty_heights(self, n: int, device, dtype) -> torch.Tensor:
        return torch.zeros((n, *self.shape), device=device, dtype=dtype)

    def read(self, heights: torch.Tensor, origins: torch.Tensor, rotations: torch.Tensor):
        a, b = rotations[:, 0, 0], rotations[:, 1, 0]
        norm = torch.hypot(a, b).clamp(min=MIN_NORM)
        shift = (origins[:, [1, 0]] - self.min) * self.inv_cell  # (N, 2): (row, column)
        coords = (
            (a / norm)[:, None, None] * self.cos_part
            + (b / norm)[:, None, None] * self.sin_part
            + shift[:, :, None]
        )  # (N, 2, P)
        rows, cols = self.shape
        r = coords[:, 0].clamp(0.0, rows - 1)
        c = coords[:, 1].clamp(0.0, cols - 1)
        r0 = r.floor().clamp(max=rows - 2)
        c0 = c.floor().clamp(max=cols - 2)
        fr, fc = r - r0, c - c0
        flat = heights.reshape(len(heights), -1)
        base = r0.long() * cols + c0.long()

        def at(offset):
            return flat.gather(1, base + offset)

        top = at(0) * (1 - fc) + at(1) * fc
        bottom = at(cols) * (1 - fc) + at(cols + 1) * fc
        return top * (1 - fr) + bottom * fr - origins[:, 2:3]


class TensorTerrain3DRules(TensorTrackRules):
    """3D Terrain's rules for N worlds (see the module docstring); success is the crossing."""

    def __init__(self, rules: Terrain3DRules, device: torch.device, dtype=torch.float32):
        super().__init__(rules, device, dtype)
        self.half_width = rules.half_width

    def make_sensor(self, rules):
        if not isinstance(rules.lidar, HeightScan):
            raise ValueError(
                f"observation={type(rules.lidar).__name__}; 3D Terrain's many worlds read the "
                "height scan only (observation='height_scan')"
            )
        return TensorHeightScan(rules.lidar, self.device, self.dtype)

    def _y_pitch_yaw(self, sim: Simulation, obs: torch.Tensor):
        if self.body.planar:
            return torch.zeros_like(obs[:, 0]), obs[:, 0], torch.zeros_like(obs[:, 0])
        return sim.field("xpos")[:, self.root, 1], obs[:, 0], obs[:, 5]

    def observe(self, sim: Simulation, heights: torch.Tensor):
        x, obs = super().observe(sim, heights)
        obs[:, -1] = sim.field("xpos")[:, self.root, 1] / self.half_width
        return x, obs

    def potential(self, sim: Simulation, x: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        y, pitch, yaw = self._y_pitch_yaw(sim, obs)
        shaping = PROGRESS_GAIN * x - HEADING_PENALTY * yaw.abs() - DRIFT_PENALTY * y.abs()
        if self.body.head_angle_reward:
            shaping = shaping - ANGLE_PENALTY * pitch.abs()
        return shaping

    def outcome(self, sim: Simulation, actions, heights, prev_shaping):
        x, obs = self.observe(sim, heights)
        shaping = self.potential(sim, x, obs)
        reward = shaping - prev_shaping - self.body.torque_cost_per_unit * torque_use(actions)
        y = self._y_pitch_yaw(sim, obs)[0]
        failed = self.critical(sim) | (x < 0.0) | (y.abs() > self.half_width)
        crossed = (x > self.end_x) & ~failed
        reward = torch.where(failed, FAIL_REWARD, reward)
        return obs, reward, failed | crossed, shaping, crossed
