"""Snapshots of an env's state that restore bit-identically: physics, RNG and wrapper counters.

An env's state is a flat dict of numpy arrays and JSON scalars (str, int, float, bool, None) so a
run directory can store it as JSON + NPZ without pickle. The pieces here are shared by every env
(and by batched envs, which hold one of each per sub-env):

* `PhysicsState`: MuJoCo's integration state (`mjSTATE_INTEGRATION`: time, qpos, qvel, act,
  warm start, ctrl, applied forces, active equalities, ...) plus the model arrays the envs write
  (actuator force ranges, weld anchors). After `mj_step` MuJoCo's derived quantities (positions,
  velocities of bodies, contacts) still describe the state *before* the last integration, and the
  envs read some of them before the next step (water forces). So the physics remembers the
  integration state each control step starts from; restoring sets that state and replays the
  step, which recomputes every derived quantity exactly, then checks that the replay lands on the
  saved current state.
* `rng_state` / `rng_from_state`: a numpy bit generator's state, big integers as decimal strings.
* `get_env_state` / `set_env_state`: the same for an env made by `gymnasium.make`, with its
  TimeLimit count; `restore_wrappers` puts Gymnasium's wrappers of a restored env in the state
  of a running episode (also used by training's curriculum workers).
"""

from __future__ import annotations

from collections.abc import Mapping

import gymnasium as gym
import mujoco
import numpy as np

from acl3d import validation

INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION
PHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS | mujoco.mjtState.mjSTATE_WARMSTART
_JSON_SCALARS = (str, int, float, bool, type(None))


def check_keys(state, keys, what: str = "state") -> None:
    """A mapping holding every key in `keys` (else ValueError listing the missing ones)."""
    if not isinstance(state, Mapping):
        raise validation.fail(what, type(state).__name__, "a dict from get_state()")
    missing = [k for k in keys if k not in state]
    if missing:
        raise ValueError(f"{what}: missing key(s) {missing}; pass a dict from get_state()")


def array(state: Mapping, key: str, like: np.ndarray) -> np.ndarray:
    """state[key] as an array of `like`'s shape and dtype; finite if real (else ValueError)."""
    value = np.asarray(state[key])
    same_kind = value.dtype.kind == like.dtype.kind or (
        value.dtype.kind in "iu" and like.dtype.kind in "iu"
    )
    if value.shape != like.shape or not same_kind:
        raise validation.fail(
            f"state[{key!r}]", value, f"an array of shape {like.shape} and dtype {like.dtype}"
        )
    if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
        raise validation.fail(f"state[{key!r}]", value, "finite values")
    return value.astype(like.dtype, copy=True)


def scalar(state: Mapping, key: str, kind: str, low: float = -np.inf, high: float = np.inf):
    """state[key] as a "real", "integer" or "flag" (JSON and NPZ both give these back)."""
    value = state[key]
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    name = f"state[{key!r}]"
    if kind == "flag":
        return validation.flag(name, value)
    if kind == "integer":
        return validation.integer(name, value, low, high)
    return validation.real(name, value, low, high)


# ---------------------------------------------------------------------- physics
class PhysicsState:
    """Steps one env's physics `nstep` substeps at a time and snapshots/restores it exactly.

    Also the physics backend of one env (N = 1, see `acl3d.envs.physics`): `controls`,
    `field(name)` and `warnings` are (1, ...) views of its MjData; `set_force_caps` writes its
    model.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, nstep: int):
        self.model, self.data, self.nstep = model, data, nstep
        self.models = [model]
        self._start = np.zeros(mujoco.mj_stateSize(model, INTEGRATION))
        self.stepped = False
        self.controls = data.ctrl[None]
        self.warnings = data.warning.number[None]
        self._fields: dict[str, np.ndarray] = {}
        self._force_range = model.actuator_forcerange  # bound once: each read makes a new view

    def field(self, name: str) -> np.ndarray:
        """A live (1, ...) view of the MjData field `name`."""
        view = self._fields.get(name)
        if view is None:
            view = self._fields[name] = getattr(self.data, name)[None]
        return view

    def set_force_caps(self, index, ranges: np.ndarray) -> None:
        """Force ranges (1, len(index), 2) of actuators `index`, in this env's model."""
        self._force_range[index] = ranges[0]

    def row_data(self, i: int) -> mujoco.MjData:
        """The one env's MjData (the backend interface's per-simulation access)."""
        return self.data

    def row(self, i: int) -> PhysicsState:
        """The one simulation as a backend of one env: itself (a batched env of one steps its
        sub-env's own physics, so its rows need no `load`/`unload`)."""
        return self

    def load(self, i: int, physics: PhysicsState) -> None:
        """Nothing to take in: `physics` is this one (see `row`)."""

    def unload(self, i: int, physics: PhysicsState) -> None:
        """Nothing to write back: `physics` is this one (see `row`)."""

    @property
    def step_start(self) -> np.ndarray:
        """The integration state the last step started from (read-only view)."""
        view = self._start.view()
        view.flags.writeable = False
        return view

    def step(self) -> None:
        """`mj_step` x nstep, remembering the integration state it starts from."""
        mujoco.mj_getState(self.model, self.data, self._start, INTEGRATION)
        mujoco.mj_step(self.model, self.data, nstep=self.nstep)
        self.stepped = True

    def adopt(self, start: np.ndarray, now: np.ndarray, warnings: np.ndarray) -> None:
        """Take a state stepped elsewhere (a batch row): replay the step from `start`, which
        recomputes every derived field, then set `now` (what the replay gives) and `warnings`."""
        m, d = self.model, self.data
        mujoco.mj_setState(m, d, start, INTEGRATION)
        mujoco.mj_step(m, d, nstep=self.nstep)
        mujoco.mj_setState(m, d, now, INTEGRATION)
        d.warning.number[:] = warnings
        self._start[:] = start
        self.stepped = True

    def get(self) -> dict:
        m, d = self.model, self.data
        now = np.empty_like(self._start)
        mujoco.mj_getState(m, d, now, INTEGRATION)
        return {
            "physics/step_start": self._start.copy(),
            "physics/now": now,
            "physics/warnings": d.warning.number.copy(),
            "physics/forcerange": m.actuator_forcerange.copy(),
            "physics/eq_data": m.eq_data.copy(),
            "physics/eq_obj2id": m.eq_obj2id.copy(),
        }

    def check(self, state: Mapping) -> dict:
        """The checked physics part of `state` (nothing is changed)."""
        like = self.get()
        check_keys(state, like)
        return {key: array(state, key, value) for key, value in like.items()}

    def set(self, checked: dict) -> None:
        """Restore a `check()`ed snapshot: replay the last control step from its start state.

        Raises ValueError (after restoring the previous physics) if the replay does not land on
        the saved state: the snapshot came from another model or was edited.
        """
        previous, replayable = self.get(), self.stepped
        try:
            self._restore(checked)
        except ValueError:
            self._restore(previous, replay=replayable)
            raise

    def _restore(self, s: dict, replay: bool = True) -> None:
        m, d = self.model, self.data
        m.actuator_forcerange[:] = s["physics/forcerange"]
        m.eq_data[:] = s["physics/eq_data"]
        m.eq_obj2id[:] = s["physics/eq_obj2id"]
        replayed = np.empty(mujoco.mj_stateSize(m, PHYSICS))
        if replay:
            mujoco.mj_setState(m, d, s["physics/step_start"], INTEGRATION)
            mujoco.mj_step(m, d, nstep=self.nstep)
            mujoco.mj_getState(m, d, replayed, PHYSICS)
        mujoco.mj_setState(m, d, s["physics/now"], INTEGRATION)
        saved = np.empty_like(replayed)
        mujoco.mj_getState(m, d, saved, PHYSICS)
        d.warning.number[:] = s["physics/warnings"]
        self._start[:] = s["physics/step_start"]
        self.stepped = replay
        if replay and not np.array_equal(replayed, saved):
            raise ValueError(
                "state: replaying its last physics step does not reproduce it; "
                "it was saved by an env with another model (body, options, frame_skip) or edited"
            )


# ---------------------------------------------------------------------- random generators
def rng_state(generator: np.random.Generator, prefix: str = "rng/") -> dict:
    """A generator's bit-generator state, flat: nested keys joined by "/", big ints as strings."""
    out = {}

    def flatten(value, key):
        if isinstance(value, Mapping):
            for k, v in value.items():
                flatten(v, f"{key}/{k}" if key else k)
        elif isinstance(value, (int, np.integer)) and not isinstance(value, bool):
            out[prefix + key] = str(int(value))  # 128-bit PCG64 words do not fit JSON doubles
        else:
            out[prefix + key] = np.array(value) if isinstance(value, np.ndarray) else value

    flatten(generator.bit_generator.state, "")
    return out


def rng_from_state(state: Mapping, prefix: str = "rng/") -> np.random.Generator:
    """Inverse of `rng_state` (ValueError if the keys do not describe a bit generator)."""
    nested: dict = {}
    for key, value in state.items():
        if not key.startswith(prefix):
            continue
        *path, last = key[len(prefix) :].split("/")
        node = nested
        for part in path:
            node = node.setdefault(part, {})
        if isinstance(value, np.ndarray) and value.shape == ():
            value = value[()]
        if isinstance(value, (str, np.str_)) and last != "bit_generator":
            if not str(value).isdigit():
                raise validation.fail(prefix + key, value, "a non-negative integer in a string")
            value = int(value)
        node[last] = value
    name = nested.get("bit_generator")
    if not isinstance(name, (str, np.str_)) or not isinstance(
        getattr(np.random, str(name), None), type
    ):
        raise validation.fail(f"state[{prefix + 'bit_generator'!r}]", name, "a numpy bit generator")
    bit_generator = getattr(np.random, str(name))()
    try:
        bit_generator.state = {**nested, "bit_generator": str(name)}
    except (TypeError, ValueError, KeyError) as exc:
        raise ValueError(f"state[{prefix!r}...]: not a {name} state ({exc})") from None
    return np.random.Generator(bit_generator)


def is_serialisable(state: Mapping) -> bool:
    """True if every value is a numpy array or a JSON scalar (what JSON + NPZ can store)."""
    return all(isinstance(k, str) for k in state) and all(
        isinstance(v, (np.ndarray, *_JSON_SCALARS)) for v in state.values()
    )


# ---------------------------------------------------------------------- wrapped envs
def get_env_state(env: gym.Env) -> dict:
    """`env.unwrapped.get_state()` plus the step count of the env's TimeLimit wrapper
    (`wrappers/<depth>/_elapsed_steps`), for an env made by `gymnasium.make`."""
    state = dict(env.unwrapped.get_state())
    for depth, wrapper in _time_limits(env):
        state[f"wrappers/{depth}/_elapsed_steps"] = wrapper._elapsed_steps
    return state


def set_env_state(env: gym.Env, state: Mapping) -> None:
    """Inverse of `get_env_state` on an env made with the same arguments."""
    elapsed = 0
    for depth, _ in _time_limits(env):
        key = f"wrappers/{depth}/_elapsed_steps"
        check_keys(state, [key])
        elapsed = scalar(state, key, "integer", 0)
    env.unwrapped.set_state({k: v for k, v in state.items() if not k.startswith("wrappers/")})
    restore_wrappers(env, elapsed)


def restore_wrappers(env: gym.Env, elapsed_steps: int) -> None:
    """Gymnasium's wrappers of a restored env, as after `elapsed_steps` steps of a running
    episode: TimeLimit's step count, OrderEnforcing's reset flag, and PassiveEnvChecker's
    once-only checks marked done (its reference data from the first reset is not state)."""
    while isinstance(env, gym.Wrapper):
        if isinstance(env, gym.wrappers.TimeLimit):
            env._elapsed_steps = elapsed_steps
        elif isinstance(env, gym.wrappers.OrderEnforcing):
            env._has_reset = True
        elif isinstance(env, gym.wrappers.PassiveEnvChecker):
            env.checked_reset = env.checked_step = env.checked_data_reuse = True
        env = env.env


def _time_limits(env: gym.Env):
    depth = 0
    while isinstance(env, gym.Wrapper):
        if isinstance(env, gym.wrappers.TimeLimit):
            yield depth, env
        env, depth = env.env, depth + 1
