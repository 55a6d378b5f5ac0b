"""Stump and Hexagon Tracks as N worlds of one simulation on MuJoCo Warp, tensors in and out.

`ManyWorldTracks` implements `acl3d.envs.tensor_vector.TensorVectorEnv` (what a torch-native
student trains on): one compiled model (from a `TrackEnv` of the same arguments), N worlds on
`acl3d.sim.warp_backend.WarpSimulation` with per-world terrain and servo caps, the tracks' rules
on torch (`TensorTrackRules`), episode sums in one `EpisodeStatistics` on the device, and a
`CurriculumSync` that learns from finished episodes and hands out the next tasks.

A step: servos (per-world force caps) -> `frame_skip` substeps (one CUDA graph) -> rules ->
episode statistics; then, if any world finished, one batched reset of those worlds: their
curriculum tasks, their terrain, their bodies placed and pushed, and one `forward` of the
simulation (a graph too). Plain stumps (Stump Tracks' task space) are built for all resetting
worlds at once on the device (`TensorStumpTracks`, draws from a torch generator seeded at
`reset(seed)`); other track kinds by the track's own generator on the CPU, world i on its own RNG
stream seeded seed + i as a single env, uploaded in one copy.

Differences from a single `TrackEnv` (docs/architecture.md): float32 physics on Warp; a reset
world's first observation is taken right after its body is placed (the single env plays one
idle step first); a diverged world (non-finite state) ends its episode flagged `unstable` with
reward 0.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch
from gymnasium.utils import seeding

from acl3d import validation
from acl3d.envs import REGISTRY, env_id
from acl3d.envs.arena import CONTROL_DT, INIT_PUSH
from acl3d.envs.episode_statistics import CurriculumSync, EpisodeStatistics
from acl3d.envs.tensor_terrain import TensorStumpTracks
from acl3d.envs.tensor_track_rules import TensorTrackRules
from acl3d.envs.track_env import TrackEnv
from acl3d.sim.warp_backend import WarpSimulation
from acl3d.sim.worlds import MAX_WORLDS, WorldFields
from acl3d.terrain.tracks import MAX_TERRAIN_HEIGHT

TRACK_WORLD_FIELDS = WorldFields(("terrain",), ("terrain",), force_caps=True)
TRACK_ENTRY_POINT = "acl3d.envs.track_env:TrackEnv"


def check_many_worlds(name: str):
    """The registration of a registered env (an id or short name) the many-world simulation
    runs: Stump and Hexagon Tracks today; ValueError naming the env for the other families."""
    gym_id = env_id(name)
    registration = next(r for r in REGISTRY.values() if r.id == gym_id)
    if registration.entry_point != TRACK_ENTRY_POINT:
        tracks = [r.id for r in REGISTRY.values() if r.entry_point == TRACK_ENTRY_POINT]
        raise ValueError(
            f"env={name!r} on the many-world simulation (vec_env warp); valid: "
            f"{', '.join(tracks)} (Parkour and 3D Terrain run on the CPU batched env)"
        )
    return registration


def many_worlds(name: str, num_envs: int, device, curriculum=None, **env_kwargs):
    """The many-world simulation of a registered env (see `check_many_worlds`)."""
    registration = check_many_worlds(name)
    return ManyWorldTracks(
        num_envs, device=device, curriculum=curriculum, **registration.kwargs, **env_kwargs
    )


class ManyWorldTracks:
    """N worlds of Stump or Hexagon Tracks on MuJoCo Warp (see the module docstring).

    Args:
        num_envs: number of worlds, in [1, 2**20].
        device: "cuda" (a GPU) or "cpu" (Warp's CPU device: slow, for tests).
        curriculum: where tasks come from (`CurriculumSync`); None: every world plays the task
            space's default task.
        max_episode_steps: the time limit (2000, as the registered envs).
        **env_kwargs: the `TrackEnv` arguments (track, body, planar, task_parameters, ...).
    """

    def __init__(
        self,
        num_envs: int,
        device="cuda",
        curriculum: CurriculumSync | None = None,
        max_episode_steps: int = 2000,
        **env_kwargs,
    ):
        self.num_envs = validation.integer("num_envs", num_envs, 1, MAX_WORLDS)
        self.max_episode_steps = validation.integer(
            "max_episode_steps", max_episode_steps, 1, 10**9
        )
        self.device = torch.device(device)
        self.template = env = TrackEnv(**env_kwargs)
        self.task_space, self.curriculum_profile = env.task_space, env.curriculum_profile
        self.curriculum = curriculum
        self.observation_size, self.action_size = env.rules.obs_size, env.body.action_size
        self.action_low = torch.as_tensor(env.action_space.low, dtype=torch.float32)
        self.action_high = torch.as_tensor(env.action_space.high, dtype=torch.float32)
        self.sim = WarpSimulation(
            env.model, self.num_envs, env.frame_skip, TRACK_WORLD_FIELDS, self.device
        )
        self.rules = TensorTrackRules(env.rules, self.device, self.sim.dtype)
        n, f = self.num_envs, {"device": self.device, "dtype": self.sim.dtype}
        self.heights = self.rules.lidar.empty_heights(n, **f)
        self.prev_shaping = torch.zeros(n, **f)
        self.elapsed = torch.zeros(n, dtype=torch.long, device=self.device)
        self.stats = EpisodeStatistics(n, len(self.task_space.names), device=self.device)
        self.tasks = np.tile(self.task_space.to_vector({}), (n, 1))
        self.terrain = TensorStumpTracks(
            env.arena.grid, tuple(self.task_space.names), env.arena.start_pad, self.device
        )
        self._generator = torch.Generator(device=self.device)
        self._rngs: list = []  # the CPU generator's per-world streams (other track kinds)
        self._success_return = env.curriculum_profile.success_return
        self._home_qpos, self._push_scale = self._home_state()
        self.obs = torch.zeros((n, self.observation_size), **f)

    def _home_state(self) -> tuple[np.ndarray, float]:
        """The placed body's qpos and the push's velocity per unit of force (`Arena.place_body`)."""
        env = self.template
        data = mujoco.MjData(env.model)
        env.arena.bound.place(data, env.arena.start_x, env.body.spawn_height)
        scale = CONTROL_DT / env.arena.bound.total_mass if env.body.initial_push else 0.0
        return data.qpos.copy(), scale

    # ------------------------------------------------------------------ resets
    def reset(self, seed: int | None = None) -> torch.Tensor:
        """Every world starts an episode, its terrain and push drawn from `seed` (see the module
        docstring)."""
        n = self.num_envs
        seed = validation.seed(seed)
        if seed is None:
            self._generator.seed()
        else:
            self._generator.manual_seed(seed)
        if not self.terrain.supported:
            self._rngs = [
                seeding.np_random(None if seed is None else seed + i)[0] for i in range(n)
            ]
        ids = np.arange(n)
        tasks = self._next_tasks(self.stats.pop(), ids)
        self.obs = self._reset_worlds(ids, tasks, self.obs)
        return self.obs

    def _next_tasks(self, finished, ids: np.ndarray) -> np.ndarray:
        if self.curriculum is None:
            return self.tasks[ids]
        tasks = np.asarray(self.curriculum.sync(finished.numpy(), ids), dtype=np.float64)
        return tasks.reshape(len(ids), -1)

    def _new_terrain(self, ids: np.ndarray, tasks: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """(heights (k, ncol), push velocities (k,)) of the resetting worlds' new episodes."""
        f64 = {"device": self.device, "dtype": torch.float64}
        if self.terrain.supported:
            normals = self.terrain.draws(len(ids), self._generator)
            lines = self.terrain.heights(torch.as_tensor(tasks, **f64), normals)
            push = (
                torch.rand(len(ids), generator=self._generator, **f64) * (2 * INIT_PUSH) - INIT_PUSH
            )
            return lines, push
        env = self.template
        lines, push = np.empty((len(ids), env.arena.grid.ncol)), np.empty(len(ids))
        for row, (i, task) in enumerate(zip(ids, tasks)):
            task = self.task_space.to_dict(task)
            env.composition.check_buildable(task)  # a teacher's unbuildable task is its bug
            lines[row] = env.generator.heights(task, self._rngs[i], env.arena.start_pad)
            push[row] = self._rngs[i].uniform(-INIT_PUSH, INIT_PUSH)
        return torch.as_tensor(lines, **f64), torch.as_tensor(push, **f64)

    def _reset_worlds(self, ids: np.ndarray, tasks: np.ndarray, obs: torch.Tensor):
        """New episodes on worlds `ids` (host indices) with `tasks`; returns obs with their rows
        replaced by their first observations."""
        env, n = self.template, self.num_envs
        self.tasks[ids] = tasks
        lines, push = self._new_terrain(ids, tasks)
        index = torch.as_tensor(ids, device=self.device)
        lines_t = lines.to(self.sim.dtype)
        self.heights[index, : lines.shape[1]] = lines_t
        terrain = self.sim.terrain("terrain")
        terrain[index] = (lines_t / MAX_TERRAIN_HEIGHT).clamp(0.0, 1.0)[:, None, :]
        mask = torch.zeros(n, dtype=torch.bool, device=self.device)
        mask[index] = True
        qpos = torch.as_tensor(self._home_qpos, device=self.device).expand(n, -1)
        qvel = torch.zeros((n, env.model.nv), device=self.device, dtype=self.sim.dtype)
        qvel[index, env.arena.bound.root_dof] = (push * self._push_scale).to(self.sim.dtype)
        self.sim.reset_worlds(mask, qpos, qvel)
        x, first = self.rules.observe(self.sim, self.heights)
        shaping = self.rules.potential(x, first)
        self.prev_shaping = torch.where(mask, shaping, self.prev_shaping)
        self.elapsed.masked_fill_(mask, 0)
        self.stats.begin(index, torch.as_tensor(tasks, device=self.device))
        return torch.where(mask[:, None], first, obs)

    # ------------------------------------------------------------------ steps
    def step(self, actions: torch.Tensor):
        """(obs, rewards, terminated, truncated, infos) with same-step autoreset; infos:
        final_obs, success, unstable, episode_return and episode_length (rows of finished
        worlds)."""
        if actions.shape != (self.num_envs, self.action_size):
            raise ValueError(
                f"actions: expected shape {(self.num_envs, self.action_size)}, "
                f"got {tuple(actions.shape)}"
            )
        a = actions.to(self.device, self.sim.dtype)
        self.rules.servo(a, self.sim)
        self.sim.step()
        obs, reward, terminated, shaping = self.rules.outcome(
            self.sim, a, self.heights, self.prev_shaping
        )
        self.prev_shaping = shaping
        unstable = ~torch.isfinite(obs).all(dim=1) | ~torch.isfinite(reward)
        obs = obs.masked_fill(unstable[:, None], 0.0)
        reward = reward.masked_fill(unstable, 0.0)
        terminated |= unstable
        self.elapsed += 1
        truncated = (self.elapsed >= self.max_episode_steps) & ~terminated
        returns = self.stats.returns + reward.double()
        success = returns > self._success_return
        infos = {
            "final_obs": obs,
            "success": success,
            "unstable": unstable,
            "episode_return": returns,
            "episode_length": self.elapsed.clone(),
        }
        self.stats.step(reward, terminated, truncated, success)
        done = terminated | truncated
        ids = done.nonzero()[:, 0].cpu().numpy()  # the step's one host sync
        if len(ids):
            tasks = self._next_tasks(self.stats.pop(), ids)
            obs = self._reset_worlds(ids, tasks, obs)
        self.obs = obs
        return obs, reward, terminated, truncated, infos

    # ------------------------------------------------------------------ checkpoints
    _SIM_FIELDS = ("qpos", "qvel", "qacc_warmstart", "ctrl", "time")

    def get_state(self) -> dict:
        """Every world's running episode as numpy arrays (physics state, terrain, rules, episode
        sums, tasks, the terrain generators' states), for a checkpoint."""
        sim = self.sim
        state = {f"sim/{name}": _host(sim.field(name)) for name in self._SIM_FIELDS}
        state.update(
            {
                "sim/force_caps": _host(sim.force_caps()),
                "sim/terrain": _host(sim.terrain("terrain")),
                "heights": _host(self.heights),
                "prev_shaping": _host(self.prev_shaping),
                "elapsed": _host(self.elapsed),
                "obs": _host(self.obs),
                "tasks": self.tasks.copy(),
                "stats": self.stats.state_dict(),
                "generator": _host(self._generator.get_state()),
                "rngs": [rng.bit_generator.state for rng in self._rngs],
            }
        )
        return state

    def set_state(self, state: dict) -> None:
        """Continue from `get_state()` of worlds built with the same arguments."""
        expected = (self.num_envs, self.observation_size)
        if tuple(np.shape(state.get("obs"))) != expected:
            raise ValueError(
                f"state['obs'] has shape {np.shape(state.get('obs'))}; these worlds: {expected}"
            )
        sim = self.sim
        for name in self._SIM_FIELDS:
            sim.field(name).copy_(torch.as_tensor(state[f"sim/{name}"]))
        sim.force_caps().copy_(torch.as_tensor(state["sim/force_caps"]))
        sim.terrain("terrain").copy_(torch.as_tensor(state["sim/terrain"]))
        for name in ("heights", "prev_shaping", "elapsed", "obs"):
            getattr(self, name).copy_(torch.as_tensor(state[name]))
        self.tasks[:] = state["tasks"]
        self.stats.load_state_dict(state["stats"])
        self._generator.set_state(torch.as_tensor(state["generator"], dtype=torch.uint8))
        self._rngs = [seeding.np_random(None)[0] for _ in state["rngs"]]
        for rng, rng_state in zip(self._rngs, state["rngs"]):
            rng.bit_generator.state = rng_state

    def close(self) -> None:
        self.template.close()


def _host(tensor: torch.Tensor) -> np.ndarray:
    """A numpy copy (on the CPU, `.numpy()` alone would share the simulation's live memory)."""
    return tensor.detach().cpu().numpy().copy()
