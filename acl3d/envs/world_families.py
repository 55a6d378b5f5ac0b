"""What each env family brings to the many-world simulation (`acl3d.envs.many_worlds`).

A family is its compiled single env (the template: model, arena, generator, rules), the
fields its worlds change (`WorldFields`), the same rules on torch, and how resetting worlds get their
terrain: the heights its terrain sensor reads and the heightfield rows the physics collides
with. `ManyWorlds` does the rest (stepping, episode statistics, resets, curriculum, checkpoints)
the same way for every family.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import mujoco
import numpy as np
import torch

from acl3d import validation
from acl3d.envs.arena import INIT_PUSH
from acl3d.envs.array_ops import TorchOps
from acl3d.envs.height_scan import HeightScan
from acl3d.envs.lidar import HeightLineLidar
from acl3d.envs.parkour_arena import GROUND_RANGE
from acl3d.envs.parkour_env import ParkourEnv
from acl3d.envs.tensor_parkour_rules import TensorParkourRules
from acl3d.envs.tensor_parkour_terrain import TensorParkourTerrain
from acl3d.envs.tensor_terrain import TensorStumpTracks
from acl3d.envs.tensor_terrain3d import TensorTerrain3D
from acl3d.envs.terrain3d_env import Terrain3DEnv
from acl3d.envs.track_env import TrackEnv
from acl3d.envs.track_rules import TrackRules
from acl3d.sim.graphed import GraphedCall
from acl3d.sim.worlds import WorldFields
from acl3d.terrain.parkour import BUILDABLE as PARKOUR_BUILDABLE
from acl3d.terrain.terrain3d import buildable_range
from acl3d.terrain.tracks import MAX_TERRAIN_HEIGHT

TERRAIN = WorldFields(("terrain",), ("terrain",), force_caps=True)
F64 = torch.float64


class WorldFamily(ABC):
    """One env family on the many-world simulation.

    Subclasses set `template` (the compiled single env of the family's arguments) and `rules`
    (its rules on torch); `fields` is what a world changes in the model.
    """

    template: TrackEnv
    rules: TrackRules
    fields: WorldFields = TERRAIN

    def __init__(self, device: torch.device):
        self.device = device

    @abstractmethod
    def terrain(self, ids, tasks, generator, rngs) -> tuple[torch.Tensor, torch.Tensor]:
        """(sensor heights (k, ...), heightfield rows (k, nrow, ncol) in [0, 1]) of the k
        resetting worlds `ids` (host indices) on `tasks` (k, d), drawn from the torch
        `generator` or the worlds' own numpy `rngs`."""

    def uses_world_rngs(self) -> bool:
        """Whether resets draw from one numpy RNG per world (a CPU generator's streams)."""
        return True

    def push(self, ids, generator, rngs) -> torch.Tensor:
        """(k,) horizontal pushes (`Arena.place_body`), after the terrain's draws."""
        if not self.uses_world_rngs():
            u = torch.rand(len(ids), generator=generator, device=self.device, dtype=F64)
            return u * (2 * INIT_PUSH) - INIT_PUSH
        draws = [rngs[i].uniform(-INIT_PUSH, INIT_PUSH) for i in ids]
        return torch.as_tensor(draws, device=self.device, dtype=F64)

    def _buildable_columns(self, ranges: dict[str, tuple[float, float]]) -> np.ndarray:
        """(2, d) low and high of every task-vector column from the generator's buildable
        range of each parameter."""
        space = self.template.task_space
        bounds = np.empty((2, space.dim))
        for name in space.names:
            bounds[:, space.slice(name)] = np.asarray(ranges[name], dtype=np.float64)[:, None]
        return bounds

    def _check_buildable(self, tasks: np.ndarray, bounds: np.ndarray) -> None:
        """Tasks (k, d) within `_buildable_columns`; a teacher's unbuildable task is its bug,
        reported in the generator's words for the first one."""
        outside = ~np.isfinite(tasks) | (tasks < bounds[0]) | (tasks > bounds[1])
        if outside.any():
            first = tasks[np.flatnonzero(outside.any(axis=1))[0]]
            self.template.composition.check_buildable(self.template.task_space.to_dict(first))

    def _cpu_heights(self, ids, tasks, rngs, generate) -> torch.Tensor:
        """The family's CPU generator, world by world on its own stream (tasks checked)."""
        space, composition = self.template.task_space, self.template.composition
        lines = []
        for i, task in zip(ids, tasks):
            task = space.to_dict(task)
            composition.check_buildable(task)  # a teacher's unbuildable task is its bug
            lines.append(generate(task, rngs[i]))
        return torch.as_tensor(np.stack(lines), device=self.device, dtype=F64)


class TrackWorlds(WorldFamily):
    """Stump and Hexagon Tracks: one height line per world (the lidar's), extruded across."""

    def __init__(self, device: torch.device, dtype: torch.dtype, **env_kwargs):
        super().__init__(device)
        self.template = env = TrackEnv(**env_kwargs)
        _check_sensor(env, HeightLineLidar, "lidar")
        self.rules = env.rules.on(TorchOps(device, dtype))
        self.stumps = TensorStumpTracks(
            env.arena.grid, tuple(env.task_space.names), env.arena.start_pad, device
        )

    def uses_world_rngs(self) -> bool:
        return not self.stumps.supported

    def terrain(self, ids, tasks, generator, rngs):
        env = self.template
        if self.stumps.supported:
            normals = self.stumps.draws(len(ids), generator)
            lines = self.stumps.heights(torch.as_tensor(tasks, device=self.device), normals)
        else:
            start = env.arena.start_pad
            lines = self._cpu_heights(
                ids, tasks, rngs, lambda task, rng: env.generator.heights(task, rng, start)
            )
        rows = (lines / MAX_TERRAIN_HEIGHT).clamp(0.0, 1.0)[:, None, :].expand(-1, 2, -1)
        return lines, rows


class Terrain3DWorlds(WorldFamily):
    """3D Terrain: one 2D field per world, read by the height scan, built for all resetting
    worlds at once on the device (`TensorTerrain3D`; the CPU generator took 0.13 ms a world)."""

    def __init__(self, device: torch.device, dtype: torch.dtype, **env_kwargs):
        super().__init__(device)
        self.template = env = Terrain3DEnv(**env_kwargs)
        _check_sensor(env, HeightScan, "height_scan")
        self.rules = env.rules.on(TorchOps(device, dtype))
        names = tuple(env.task_space.names)
        self.fields3d = TensorTerrain3D(env.arena.generator, names, device)
        self._buildable = self._buildable_columns({n: buildable_range(n) for n in names})
        # ~330 tensor operations a reset: one CUDA graph per 64 resetting worlds
        self._build = GraphedCall(self._fields, self.device, rows_step=64, max_rows=1024)

    def uses_world_rngs(self) -> bool:
        return False

    def terrain(self, ids, tasks, generator, rngs):
        tasks = np.asarray(tasks, dtype=np.float64)
        self._check_buildable(tasks, self._buildable)
        draws = self.fields3d.draws(len(ids), generator)
        tasks = torch.as_tensor(tasks, device=self.device)
        return self._build(tasks, *(draws[name] for name in TensorTerrain3D.DRAWS))

    def _fields(self, tasks, *draws) -> tuple[torch.Tensor, torch.Tensor]:
        """(heights, heightfield rows) of tasks (k, d) and their draws, in `DRAWS` order."""
        field = self.fields3d.heights(tasks, dict(zip(TensorTerrain3D.DRAWS, draws)))
        return field, self.template.arena.fractions(field).clamp(0.0, 1.0)


class ParkourWorlds(WorldFamily):
    """Parkour: ground and ceiling heightfields, water level and creepers per world, built on
    the device for all resetting worlds at once (`TensorParkourTerrain`: the CPPN as batched
    matrix products) as each world's record (`TensorParkourRules`).

    Climbers hang from the start-pad ceiling: as every world places its body at the same
    height, each climber's world is moved down by the lift the single env gives its body (a
    translation in z, which changes neither the physics nor the observation). Creepers must be
    static (`movable_creepers=False`, the benchmark's): swinging ones would need per-world
    bodies and weld targets.
    """

    def __init__(self, device: torch.device, dtype: torch.dtype, **env_kwargs):
        super().__init__(device)
        if env_kwargs.get("movable_creepers"):
            raise ValueError(
                "movable_creepers=True on the many-world simulation; valid: False (static "
                "creepers; swinging ones run on the CPU batched env)"
            )
        self.template = env = ParkourEnv(**env_kwargs)
        self.rules = TensorParkourRules(env.rules, TorchOps(device, dtype))
        climbing = env.arena.climbing
        self.fields = WorldFields(
            ("terrain", "ceiling"), ("terrain", "ceiling"), True, climbing is not None
        )
        hand_top = None
        if climbing is not None:  # the highest hand's top with the body placed at home
            data = mujoco.MjData(env.model)
            env.arena.bound.place(data, env.arena.start_x, env.body.spawn_height)
            mujoco.mj_kinematics(env.model, data)
            hand_top = float((data.geom_xpos[climbing.geom_ids, 2] + climbing.radius).max())
        self._buildable = self._buildable_columns(PARKOUR_BUILDABLE)
        self.parkour_terrain = TensorParkourTerrain(
            env.arena.generator, env.task_space, self.rules.record, env.arena.grid.x, hand_top,
            device,
        )  # fmt: skip

    def push(self, ids, generator, rngs) -> torch.Tensor:
        if self.template.body.initial_push:
            return super().push(ids, generator, rngs)
        return torch.zeros(len(ids), device=self.device, dtype=F64)  # the fish: none drawn

    def uses_world_rngs(self) -> bool:
        return False

    def terrain(self, ids, tasks, generator, rngs):
        tasks = np.asarray(tasks, dtype=np.float64)
        self._check_buildable(tasks, self._buildable)
        normals = self.parkour_terrain.draws(len(ids), generator)
        records = self.parkour_terrain.records(torch.as_tensor(tasks, device=self.device), normals)
        lo, hi = GROUND_RANGE
        ground = (self.rules.record(records, "ground") - lo) / (hi - lo)
        return records, ground[:, None, :].expand(-1, 2, -1)


def _check_sensor(env: TrackEnv, sensor: type, observation: str) -> None:
    """The family's worlds read their terrain rows with one sensor (the one its terrain fills)."""
    if not isinstance(env.rules.lidar, sensor):
        raise validation.fail(
            "observation",
            env.composition.observation,
            f"{observation!r} on the many-world simulation (another runs on the CPU envs)",
        )


# the family of each registered single env (its entry point)
FAMILIES: dict[str, type[WorldFamily]] = {
    "acl3d.envs.track_env:TrackEnv": TrackWorlds,
    "acl3d.envs.terrain3d_env:Terrain3DEnv": Terrain3DWorlds,
    "acl3d.envs.parkour_env:ParkourEnv": ParkourWorlds,
}
