"""Env families as N worlds of one simulation on MuJoCo Warp, tensors in and out.

`ManyWorlds` implements `acl3d.envs.tensor_vector.TensorVectorEnv` (what a torch-native student
trains on) for any `acl3d.envs.world_families.WorldFamily`: Stump and Hexagon Tracks
(`ManyWorldTracks`) and 3D Terrain. One compiled model (the family's single env of the same
arguments), N worlds on `acl3d.sim.warp_backend.WarpSimulation` with per-world terrain and servo
caps, the family's rules on torch, episode sums in one `EpisodeStatistics` on the device, and a
`CurriculumSync` that learns from finished episodes and hands out the next tasks.

A step: servos (per-world force caps) -> `frame_skip` substeps (one CUDA graph) -> rules ->
episode statistics; then, if any world finished, one batched reset of those worlds: their
curriculum tasks, their terrain, their bodies placed and pushed, and their first observations
from a `forward` of a small second simulation, the start worlds (a graph too), so that resets
cost physics in proportion to the worlds that reset, not to N. Plain stumps (Stump Tracks' task space) are built for all resetting
worlds at once on the device (`TensorStumpTracks`, draws from a torch generator seeded at
`reset(seed)`); other terrain by the family's own generator on the CPU, world i on its own RNG
stream seeded seed + i as a single env, uploaded in one copy.

Differences from a single env (docs/architecture.md): float32 physics on Warp; a reset world's
first observation is taken right after its body is placed (the single env plays one idle step
first); a diverged world (non-finite state) ends its episode flagged `unstable` with reward 0.
"""

from __future__ import annotations

import secrets

import gymnasium as gym
import mujoco
import numpy as np
import torch
from gymnasium.utils import seeding

from acl3d import devices, validation
from acl3d.envs import REGISTRY, env_id
from acl3d.envs.arena import CONTROL_DT
from acl3d.envs.episode_statistics import CurriculumSync, EpisodeStatistics
from acl3d.envs.world_families import FAMILIES, TrackWorlds, WorldFamily
from acl3d.sim.graphed import GraphedCall
from acl3d.sim.warp_backend import WarpSimulation
from acl3d.sim.worlds import MAX_WORLDS

DTYPE = torch.float32  # MuJoCo Warp's
# Resetting worlds get their first observations on a second, small simulation of N / 16 worlds
# (at least 64): about 4x the worlds that reset in a step at 4,096 worlds or more; a larger burst
# (every world at once, the time limit) is done in parts.
START_SHARE, MIN_START_WORLDS = 16, 64


def check_many_worlds(name: str):
    """The registration of a registered env (an id or short name) the many-world simulation
    runs: Stump Tracks, Hexagon Tracks, Parkour (static creepers) and 3D Terrain; ValueError
    naming the env otherwise."""
    gym_id = env_id(name)
    registration = next(r for r in REGISTRY.values() if r.id == gym_id)
    if registration.entry_point not in FAMILIES:
        valid = [r.id for r in REGISTRY.values() if r.entry_point in FAMILIES]
        raise ValueError(
            f"env={name!r} on the many-world simulation (vec_env warp); valid: {', '.join(valid)}"
        )
    return registration


def many_worlds(
    name: str,
    num_envs: int,
    device,
    curriculum=None,
    autoreset=True,
    constraint_rows: int | None = None,
    contact_slots: int | None = None,
    **env_kwargs,
):
    """The many-world simulation of a registered env (see `check_many_worlds`)."""
    registration = check_many_worlds(name)
    kwargs = {**registration.kwargs, **env_kwargs}
    steps = kwargs.pop("max_episode_steps", 2000)
    device = devices.usable(device)
    family = FAMILIES[registration.entry_point](device, DTYPE, **kwargs)
    return ManyWorlds(
        num_envs, family, curriculum=curriculum, max_episode_steps=steps, autoreset=autoreset,
        constraint_rows=constraint_rows, contact_slots=contact_slots,
    )  # fmt: skip


class ManyWorlds:
    """N worlds of one env family on MuJoCo Warp (see the module docstring).

    Args:
        num_envs: number of worlds, in [1, 2**20].
        family: the env family (its template env, rules on torch and terrain), built for the
            device the worlds live on: a GPU ("cuda") or Warp's CPU device ("cpu", for tests).
        curriculum: where tasks come from (`CurriculumSync`); None: every world plays the task
            in `tasks` (the task space's default task until set).
        max_episode_steps: the time limit (2000, as the registered envs).
        start_worlds: worlds of the start simulation, where resetting worlds get their first
            observation; None: N / 16, at least 64 (at most N).
        autoreset: a finished world starts its next episode in the same step (True); False:
            it plays on, its results to be ignored, until `reset` (single-episode passes such
            as evaluations, which read each world's results from the infos of the step that
            ends its episode: a step then never waits for the GPU, nor books episodes).
        constraint_rows, contact_slots: constraint rows and contact slots reserved per world
            (`WarpSimulation`); None: MuJoCo Warp's estimates from the model.
    """

    def __init__(
        self,
        num_envs: int,
        family: WorldFamily,
        curriculum: CurriculumSync | None = None,
        max_episode_steps: int = 2000,
        start_worlds: int | None = None,
        autoreset: bool = True,
        constraint_rows: int | None = None,
        contact_slots: int | None = None,
    ):
        self.num_envs = validation.integer("num_envs", num_envs, 1, MAX_WORLDS)
        self.autoreset = validation.flag("autoreset", autoreset)
        if start_worlds is None:
            start_worlds = min(self.num_envs, max(MIN_START_WORLDS, self.num_envs // START_SHARE))
        validation.integer("start_worlds", start_worlds, 1, self.num_envs)
        self.max_episode_steps = validation.integer(
            "max_episode_steps", max_episode_steps, 1, 10**9
        )
        self.family, self.device = family, family.device
        self.template = env = family.template
        self.task_space, self.curriculum_profile = env.task_space, env.curriculum_profile
        self.curriculum = curriculum
        self.observation_size, self.action_size = env.rules.obs_size, env.body.action_size
        self.action_low = torch.as_tensor(env.action_space.low, dtype=torch.float32)
        self.action_high = torch.as_tensor(env.action_space.high, dtype=torch.float32)
        self.sim, self.starts = (
            WarpSimulation(
                env.model,
                n,
                env.frame_skip,
                family.fields,
                self.device,
                constraint_rows,
                contact_slots,
            )  # fmt: skip
            for n in (self.num_envs, start_worlds)
        )
        self.rules = family.rules
        n, f = self.num_envs, {"device": self.device, "dtype": self.sim.dtype}
        self.heights = self.rules.lidar.batch_heights(n)
        self._start_heights = self.rules.lidar.batch_heights(start_worlds)
        # ~300 tensor operations a reset, on the start worlds' fixed arrays: one CUDA graph
        self._observe_starts = GraphedCall(self._start_observations, self.device)
        self.prev_shaping = torch.zeros(n, **f)
        self.elapsed = torch.zeros(n, dtype=torch.long, device=self.device)
        self.stats = EpisodeStatistics(n, self.task_space.dim, device=self.device)
        self.tasks = np.tile(self.task_space.to_vector({}), (n, 1))
        self._generator = torch.Generator(device=self.device)
        self._rngs: list = []  # per-world streams of a CPU terrain generator
        self._home_qpos, self._push_scale = self._home_state()
        self.obs = torch.zeros((n, self.observation_size), **f)
        self._running = False  # every world in an episode: after reset() or set_state()

    def _home_state(self) -> tuple[np.ndarray, float]:
        """The placed body's qpos and the push's velocity per unit of force (`Arena.place_body`)."""
        env = self.template
        data = mujoco.MjData(env.model)
        env.arena.bound.place(data, env.arena.start_x, env.body.spawn_height)
        scale = CONTROL_DT / env.arena.bound.total_mass if env.body.initial_push else 0.0
        return data.qpos.copy(), scale

    # ------------------------------------------------------------------ resets
    def reset(self, seed: int | None = None, period: int | None = None) -> torch.Tensor:
        """Every world starts an episode, its terrain and push drawn from `seed` (see the module
        docstring; None: a random seed).

        period: worlds i and i + period draw the same terrain and push, as worlds 0..period-1 of
        `period` worlds reset with `seed` would (copies of one set of episodes: several policies
        evaluated side by side on the same tracks); None: N.
        """
        n = self.num_envs
        period = n if period is None else validation.integer("period", period, 1, n)
        seed = validation.seed(seed)
        if seed is None:
            seed = secrets.randbelow(2**31)
        if self.family.uses_world_rngs():
            self._rngs = [seeding.np_random(seed + i % period)[0] for i in range(n)]
        ids = np.arange(n)
        tasks = self._next_tasks(self.stats.pop(), ids)
        for lo in range(0, n, period):
            self._generator.manual_seed(seed)
            block = ids[lo : lo + period]
            self.obs = self._reset_worlds(block, tasks[block], self.obs)
        self._running = True
        return self.obs

    def _next_tasks(self, finished, ids: np.ndarray) -> np.ndarray:
        """The next task of each world `ids`: the curriculum's, checked as a batch (finite,
        one row a world, buildable) before any world is reset with them."""
        if self.curriculum is None:
            return self.tasks[ids]
        tasks = validation.real_array(
            "the curriculum's tasks",
            self.curriculum.sync(finished.numpy(), ids),
            shape=(len(ids), self.task_space.dim),
        )
        self.template.composition.check_buildable(self.task_space.columns(tasks))
        return tasks

    def _reset_worlds(self, ids: np.ndarray, tasks: np.ndarray, obs: torch.Tensor):
        """New episodes on worlds `ids` (host indices) with `tasks`; returns a copy of obs with
        their rows replaced by their first observations."""
        env = self.template
        self.tasks[ids] = tasks
        sensed, rows = self.family.terrain(ids, tasks, self._generator, self._rngs)
        push = self.family.push(ids, self._generator, self._rngs)
        index = torch.as_tensor(ids, device=self.device)
        self.heights[index, ..., : sensed.shape[-1]] = sensed.to(self.sim.dtype)
        self.sim.terrain("terrain")[index] = rows.to(self.sim.dtype)
        qpos = torch.as_tensor(self._home_qpos, device=self.device).expand(len(ids), -1)
        qvel = torch.zeros((len(ids), env.model.nv), device=self.device, dtype=self.sim.dtype)
        qvel[:, env.arena.bound.root_dof] = (push * self._push_scale).to(self.sim.dtype)
        self.sim.reset_worlds(index, qpos, qvel)
        self.elapsed.index_fill_(0, index, 0)
        for lo in range(0, len(ids), self.starts.nworld):
            part = slice(lo, lo + self.starts.nworld)
            first, shaping = self._first_observations(index[part], qpos[part], qvel[part])
            obs = obs.index_put((index[part],), first)
            self.prev_shaping.index_put_((index[part],), shaping)
        # first observations kept for the teachers that learn from them (Self-Paced)
        self.stats.begin(index, torch.as_tensor(tasks, device=self.device), obs[index])
        return obs

    def _first_observations(self, index, qpos, qvel) -> tuple[torch.Tensor, torch.Tensor]:
        """(observations, shaping) of the k <= `starts.nworld` worlds `index` in their reset
        state, computed on the start worlds: the main simulation needs no `forward` (its next
        step computes one), so a reset costs physics for k worlds, not N."""
        k, starts = len(index), self.starts
        rows = torch.arange(k, device=self.device)
        starts.terrain("terrain")[:k] = self.sim.terrain("terrain")[index]
        starts.force_caps()[:k] = self.sim.force_caps()[index]
        starts.reset_worlds(rows, qpos, qvel)
        starts.forward()
        self._start_heights[:k] = self.heights[index]
        first, shaping = self._observe_starts(self._start_heights)
        return first[:k], shaping[:k]

    def _start_observations(self, heights) -> tuple[torch.Tensor, torch.Tensor]:
        """(observations, shaping) of every start world, reading `heights`."""
        x, obs = self.rules.observe(self.starts, heights)
        return obs, self.rules.potential(self.starts, x, obs)

    # ------------------------------------------------------------------ steps
    def step(self, actions: torch.Tensor):
        """(obs, rewards, terminated, truncated, infos) with same-step autoreset; infos:
        final_obs, success, unstable, episode_return and episode_length (rows of finished
        worlds). Before `reset` or `set_state`: gymnasium's ResetNeeded."""
        if not self._running:
            raise gym.error.ResetNeeded("step() before reset(): call reset() first")
        if actions.shape != (self.num_envs, self.action_size):
            raise ValueError(
                f"actions: expected shape {(self.num_envs, self.action_size)}, "
                f"got {tuple(actions.shape)}"
            )
        a = actions.to(self.device, self.sim.dtype)
        played = self.rules.before_physics(self.sim, a, self.heights)
        self.rules.servo(played, self.sim)
        self.sim.step()
        out = self.rules.outcome(self.sim, a, self.heights, self.prev_shaping)
        self.prev_shaping = out.shaping
        unstable = ~torch.isfinite(out.obs).all(dim=1) | ~torch.isfinite(out.reward)
        obs = out.obs.masked_fill(unstable[:, None], 0.0)
        reward = out.reward.masked_fill(unstable, 0.0)
        terminated = out.terminated | unstable
        self.elapsed += 1
        truncated = (self.elapsed >= self.max_episode_steps) & ~terminated
        returns = self.stats.returns + reward.double()
        success = self.rules.success(returns, out)
        infos = {
            "final_obs": obs,
            "success": success,
            "unstable": unstable,
            "episode_return": returns,
            "episode_length": self.elapsed.clone(),
        }
        if not self.autoreset:  # a pass of one episode a world: results read from infos
            self.stats.add(reward)
        else:
            self.stats.step(reward, terminated, truncated, success)
            ids = (terminated | truncated).nonzero()[:, 0].cpu().numpy()  # the one host sync
            if len(ids):
                tasks = self._next_tasks(self.stats.pop(), ids)
                obs = self._reset_worlds(ids, tasks, obs)
        self.obs = obs
        return obs, reward, terminated, truncated, infos

    # ------------------------------------------------------------------ checkpoints
    # the state, plus cvel and cdof_dot: MuJoCo Warp builds equality constraints (a climber's
    # weld) from the last substep's, so a restore without them parts from the original run
    _SIM_FIELDS = ("qpos", "qvel", "qacc_warmstart", "ctrl", "time", "cvel", "cdof_dot")

    def get_state(self) -> dict:
        """Every world's running episode as numpy arrays (physics state, terrain, rules, episode
        sums, tasks, the terrain generators' states), for a checkpoint; before `reset`,
        gymnasium's ResetNeeded (no episode to save)."""
        if not self._running:
            raise gym.error.ResetNeeded("get_state() needs running episodes: call reset() first")
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
            if f"sim/{name}" in state:  # checkpoints before cvel and cdof_dot were kept lack them
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
        self._running = True

    def close(self) -> None:
        self.template.close()


def _host(tensor: torch.Tensor) -> np.ndarray:
    """A numpy copy (on the CPU, `.numpy()` alone would share the simulation's live memory)."""
    return tensor.detach().cpu().numpy().copy()


class ManyWorldTracks(ManyWorlds):
    """Stump or Hexagon Tracks as N worlds (`TrackWorlds`); `env_kwargs` are `TrackEnv`'s."""

    def __init__(
        self,
        num_envs: int,
        device="cuda",
        curriculum: CurriculumSync | None = None,
        max_episode_steps: int = 2000,
        start_worlds: int | None = None,
        autoreset: bool = True,
        **env_kwargs,
    ):
        family = TrackWorlds(torch.device(device), DTYPE, **env_kwargs)
        super().__init__(num_envs, family, curriculum, max_episode_steps, start_worlds, autoreset)
