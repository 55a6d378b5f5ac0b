"""The tracks' rules on torch tensors: observation, reward and termination of N worlds at once.

The same arithmetic as `TrackRules` (TeachMyAgent §2.1: shaping 130/30 * x_head - 5 |angle|,
torque cost, -100 and termination on a critical contact or behind the start, termination past the
end line) and the same observation layout (head, motor state, grasp state, height-line lidar), in
torch on whatever device the simulation's tensors live, for the many-world simulation
(`acl3d.sim`): no per-world Python and no host round trip. Its constants (indices, gains, lidar
geometry) are read from a compiled `TrackRules`, so the two cannot drift apart;
`tests/test_many_worlds.py` checks that both give the same observations and rewards on the same
physics within float32 tolerance.
"""

from __future__ import annotations

import torch

from acl3d.envs.lidar import HeightLineLidar
from acl3d.envs.track_rules import ANGLE_PENALTY, FAIL_REWARD, PROGRESS_GAIN, TrackRules
from acl3d.sim.worlds import Simulation

_PLANAR_GAINS = (0.12, 0.08)


def _index(values, device) -> torch.Tensor:
    return torch.as_tensor(values, dtype=torch.long, device=device)


class TensorHeightLineLidar:
    """`HeightLineLidar.read_batch` on tensors: N worlds' rays on their rows of heights.

    heights: (N, ncol + reach + 1) metres, the track's columns then a -inf margin (no ray crosses
    past the track end). For each ray, the crossed segment is the first column whose running
    maximum elevation slope reaches the ray's slope (`torch.cummax` then `searchsorted` per row).
    """

    def __init__(self, lidar: HeightLineLidar, device: torch.device, dtype: torch.dtype):
        f = {"device": device, "dtype": dtype}
        self.nb_rays, self.range = lidar.nb_rays, lidar.range
        self.width = lidar._ncol + lidar._reach + 1
        self.x_min, self.cell, self.ncol, self.reach = (
            lidar._x_min, lidar._cell, lidar._ncol, lidar._reach,
        )  # fmt: skip
        pad = lidar._x[-1] + lidar._cell * torch.arange(1, self.width - lidar._ncol + 1)
        self.x = torch.cat((torch.as_tensor(lidar._x), pad)).to(**f)
        self.slope = torch.as_tensor(lidar._slope).to(**f)
        self.inv_sin = torch.as_tensor(lidar._inv_sin).to(**f)
        self.slanted = _index(lidar._slanted, device)
        self.vertical = _index(lidar._vertical, device)
        self.window = torch.arange(1, self.reach + 1, device=device)

    def empty_heights(self, n: int, device, dtype) -> torch.Tensor:
        out = torch.full((n, self.width), -torch.inf, device=device, dtype=dtype)
        out[:, : self.ncol] = 0.0
        return out

    def read(self, heights: torch.Tensor, origins: torch.Tensor, rotations=None) -> torch.Tensor:
        """(N, nb_rays) fractions of the range (1: no hit) from origins (N, 3); the roots'
        rotations are not used (the rays stay sagittal)."""
        n = heights.shape[0]
        x0, z0 = origins[:, 0], origins[:, 2]
        j = ((x0 - self.x_min) / self.cell).long().clamp_(0, self.ncol - 2)
        hj = heights.gather(1, j[:, None])[:, 0]
        hj1 = heights.gather(1, (j + 1)[:, None])[:, 0]
        h0 = hj + (x0 - self.x[j]) / self.cell * (hj1 - hj)
        cols = j[:, None] + self.window
        x0c, z0c = x0[:, None], z0[:, None]
        rise = (heights.gather(1, cols) - z0c) / (self.x[cols] - x0c)
        running = torch.cummax(rise, dim=1).values
        k = torch.searchsorted(running, self.slope.expand(n, -1).contiguous())
        hit = k < self.reach
        b = j[:, None] + 1 + k
        first = k == 0
        xa = torch.where(first, x0c, self.x[b - 1])
        ha = torch.where(first, h0[:, None], heights.gather(1, b - 1))
        xb, hb = self.x[b], heights.gather(1, b)
        m = (hb - ha) / (xb - xa)
        x_hit = (z0c - ha + m * xa - self.slope * x0c) / (m - self.slope)
        dist = torch.empty((n, self.nb_rays), device=heights.device, dtype=heights.dtype)
        dist[:, self.slanted] = torch.where(hit, (x_hit - x0c) * self.inv_sin, torch.inf)
        dist[:, self.vertical] = (z0 - h0)[:, None]
        out = torch.where(dist <= self.range, dist / self.range, 1.0)
        return out.masked_fill_((z0 <= h0)[:, None], 0.0)


class TensorTrackRules:
    """Tracks' rules for N worlds of a `Simulation` (see the module docstring).

    Args:
        rules: the compiled env's `TrackRules` (its lidar must be the height-line lidar).
        device, dtype: where and in which precision the worlds' tensors live.
    """

    def __init__(self, rules: TrackRules, device: torch.device, dtype=torch.float32):
        self.device, self.dtype = device, dtype
        self.sensor = self.make_sensor(rules)
        b, body = rules.bound, rules.body
        self.body, self.obs_size, self.end_x = body, rules.obs_size, rules.end_x
        self.head_size, self.grasp_size = rules.head_size, rules.grasp_size
        self.root, self.root_dof = b.root_id, b.root_dof
        f = {"device": device, "dtype": dtype}
        self.qpos_index = _index(b.qpos_adr, device)
        self.qvel_index = _index(b.dof_adr, device)
        self.ctrl_index = _index(b.actuator_ids, device)
        self.angle_correction = torch.as_tensor(b.angle_correction).to(**f)
        self.inv_speeds = torch.as_tensor(rules._inv_speeds).to(**f)
        self.speeds = torch.as_tensor(b.speeds).to(**f)
        self.motor_order = _index(rules._motor_order, device)
        self.motor_size = rules._motor_size
        self.contact_sensors = _index(TrackRules._sensor_adr(b.model, b.contact_geom_ids), device)
        self.critical_sensors = _index(TrackRules._sensor_adr(b.model, b.critical_geom_ids), device)
        self.nb_motors = len(b.speeds)
        self.lidar_col = rules._lidar_col
        self.planar_gains = torch.tensor(_PLANAR_GAINS, **f)

    def make_sensor(self, rules: TrackRules):
        """The terrain sensor on tensors (`read(heights, origins, rotations)`, `nb_rays`,
        `empty_heights(n, device, dtype)`): the tracks' height-line lidar."""
        if not isinstance(rules.lidar, HeightLineLidar):
            raise ValueError(
                f"observation={type(rules.lidar).__name__}; the many-world tracks read the "
                "height-line lidar only (observation='lidar')"
            )
        return TensorHeightLineLidar(rules.lidar, self.device, self.dtype)

    # ------------------------------------------------------------------ actions
    def servo(self, actions: torch.Tensor, sim: Simulation, heights: torch.Tensor) -> None:
        """Velocity servos towards speed * sign(a), force capped at torque * |a| per world;
        `heights`, the worlds' terrain rows, serve rules with per-world state (Parkour's)."""
        motors = actions[:, : self.nb_motors]
        cap = motors.abs().clamp_(max=1.0) * self.body.torque
        caps = sim.force_caps()
        caps[:, self.ctrl_index, 0] = -cap
        caps[:, self.ctrl_index, 1] = cap
        sim.field("ctrl")[:, self.ctrl_index] = self.speeds * torch.sign(motors)

    # ------------------------------------------------------------------ observation
    def head(self, sim: Simulation, out: torch.Tensor) -> torch.Tensor:
        """Write the head observation (as `TrackRules.head`); return the head's x (N,)."""
        r = sim.field("xmat")[:, self.root]
        qv, v = sim.field("qvel"), self.root_dof
        out[:, 0] = torch.atan2(r[:, 2, 0], r[:, 0, 0])
        if self.body.planar:
            out[:, 1] = qv[:, v + 2] / 25.0
            out[:, 2:4] = qv[:, v : v + 2] * self.planar_gains
        else:
            omega = sim.field("cvel")[:, self.root]
            out[:, 1] = -2.0 * omega[:, 1] / 50.0
            out[:, 2] = 0.12 * qv[:, v]
            out[:, 3] = 0.08 * qv[:, v + 2]
            out[:, 4] = torch.atan2(r[:, 2, 1], r[:, 2, 2])
            out[:, 5] = torch.atan2(r[:, 1, 0], r[:, 0, 0])
            out[:, 6] = 0.12 * qv[:, v + 1]
            out[:, 7] = 2.0 * omega[:, 0] / 50.0
            out[:, 8] = 2.0 * omega[:, 2] / 50.0
        return sim.field("xpos")[:, self.root, 0]

    def observe(self, sim: Simulation, heights: torch.Tensor):
        """(x of the head (N,), observation (N, obs_size))."""
        n = heights.shape[0]
        obs = torch.zeros((n, self.obs_size), device=self.device, dtype=self.dtype)
        x = self.head(sim, obs[:, : self.head_size])
        touched = (sim.field("sensordata")[:, self.contact_sensors] > 0.0).to(self.dtype)
        state = torch.cat(
            (
                sim.field("qpos")[:, self.qpos_index] + self.angle_correction,
                sim.field("qvel")[:, self.qvel_index] * self.inv_speeds,
                touched,
            ),
            dim=1,
        )
        motor = obs[:, self.head_size : self.head_size + self.motor_size]
        motor[:, self.motor_order] = state
        root, rotation = sim.field("xpos")[:, self.root], sim.field("xmat")[:, self.root]
        readings = self.sensor.read(heights, root, rotation)
        obs[:, self.lidar_col : self.lidar_col + self.sensor.nb_rays] = readings
        return x, obs

    def potential(self, sim: Simulation, x: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        """(N,) shaping whose differences reward a step."""
        shaping = PROGRESS_GAIN * x
        if self.body.head_angle_reward:
            shaping = shaping - ANGLE_PENALTY * obs[:, 0].abs()
        return shaping

    def critical(self, sim: Simulation) -> torch.Tensor:
        """(N,) a critical part of the body touches something."""
        if not len(self.critical_sensors):
            return torch.zeros(sim.nworld, dtype=torch.bool, device=self.device)
        return (sim.field("sensordata")[:, self.critical_sensors] > 0.0).any(dim=1)

    # ------------------------------------------------------------------ outcome
    def outcome(self, sim: Simulation, actions, heights, prev_shaping):
        """(obs, reward, terminated, shaping, success) after a physics step; `prev_shaping` (N,)
        is the last step's shaping; success None: judged by the return (the tracks)."""
        x, obs = self.observe(sim, heights)
        shaping = self.potential(sim, x, obs)
        reward = shaping - prev_shaping - self.body.torque_cost_per_unit * torque_use(actions)
        fail = self.critical(sim) | (x < 0.0)
        reward = torch.where(fail, FAIL_REWARD, reward)
        return obs, reward, fail | (x > self.end_x), shaping, None


def torque_use(actions: torch.Tensor) -> torch.Tensor:
    """(N,) sum of |a| clipped at 1: what the torque cost is proportional to."""
    return actions.abs().clamp(max=1.0).sum(dim=1)
