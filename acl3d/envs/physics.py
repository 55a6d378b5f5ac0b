"""Physics backends: N MuJoCo simulations stepped together and read as (N, ...) arrays.

The step arithmetic of the tracks (`acl3d.envs.track_rules.TrackRules.step_rows`) touches the
physics only through this interface, so the same code serves one env and a batch of them:

* `controls`: (N, nu) actuator controls, written before `step()`;
* `field(name)`: a live (N, ...) array of an MjData field: state (qpos, qvel) and the derived
  fields of the last step (xpos, xmat, cvel, sensordata), which, as after `mj_step`, describe
  the state the last substep started from;
* `warnings`: (N, mjNWARNING) warning counts (MuJoCo resets a diverged simulation and counts it);
* `set_force_caps(index, ranges)`: actuators `index` of simulation i get the force ranges
  `ranges[i]` (servo caps, written in each simulation's own model);
* `models[i]`: simulation i's own compiled model, whose fields the envs write in place between
  steps (heightfields, servo force caps, weld anchors): every env compiles its own model;
* `row_data(i)`: MjData-like access to simulation i alone, for the per-env rules that write
  forces and constraints (Parkour's water and grasps: `xfrc_applied`, `eq_active`);
* `step()`: `nstep` substeps of every simulation.

Two backends implement it. `env_state.PhysicsState` is one env's MjData stepped by `mj_step`
(N = 1; it also snapshots and restores exactly). `BatchPhysics` keeps N simulations as
`mjSTATE_INTEGRATION` rows of `mujoco.batch.Batch`, which steps them all in one call on its own
C thread pool, bit-identical to `mj_step` on each env's own MjData at any thread count. Between
steps the rows are the simulations' state: a sub-env reset on its own MjData is `load`ed into
its row, and a row is written back into the sub-env's MjData (`unload`) before anything reads
that MjData (snapshots, rendering). A GPU backend (MuJoCo Warp) would implement the same
interface: see docs/development.md.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import mujoco.batch
import numpy as np

from acl3d.envs.env_state import INTEGRATION, PhysicsState


class BatchPhysics:
    """N simulations on `mujoco.batch.Batch`, simulation i on `models[i]`.

    Args:
        models: one compiled model per simulation, all of one MjData layout (the sub-envs'
            models: same body and arena, different terrain and servo caps). The batch reads
            them live, so writes to their fields take effect at the next step.
        nstep: substeps per `step()` (the env's frame_skip).
        threads: the batch's C threads (1: the caller's thread only).
        fields: the MjData fields `field()` will be asked for (derived ones are copied out of
            each step only once bound, so they are bound here).
    """

    def __init__(
        self, models: Sequence[mujoco.MjModel], nstep: int, threads: int, fields: Sequence[str]
    ):
        self.models = list(models)
        self.n, self.nstep = len(self.models), nstep
        self.batch = mujoco.batch.Batch(self.models[0], self.n, nthread=threads)
        self.batch.set_models(self.models)
        self.state = self.batch.state  # (N, nstate): each simulation's integration state
        self.start = np.zeros_like(self.state)  # the rows the last step started from
        self.controls = self.batch.bind("ctrl")
        self.warnings = self.batch.warning[:, :, 1]  # mjWarningStat: (lastinfo, number)
        self._fields = {name: self.batch.bind(name) for name in fields}
        self.field_names = tuple(self._fields)
        self._row_data: list[RowData | None] = [None] * self.n
        # the models' force ranges, bound once (each attribute read makes a new array view)
        self._force_ranges = [model.actuator_forcerange for model in self.models]

    def field(self, name: str) -> np.ndarray:
        """Live (N, ...) array of an MjData field named in the constructor's `fields`."""
        return self._fields[name]

    def set_force_caps(self, index, ranges: np.ndarray) -> None:
        for force_range, r in zip(self._force_ranges, ranges):
            force_range[index] = r

    def step(self) -> None:
        """`nstep` substeps of every simulation, remembering the rows they started from."""
        np.copyto(self.start, self.state)
        self.batch.step(nstep=self.nstep)

    def load(self, i: int, physics: PhysicsState) -> None:
        """Make row i the state of `physics` (a sub-env's MjData, after its own reset or
        restore). Its last step is replayed from the state it started from, so that the row's
        derived fields are that MjData's too (per-env rules read them before the next step)."""
        self.state[i] = physics.step_start
        self.batch.step(ids=[i], nstep=self.nstep)
        mujoco.mj_getState(physics.model, physics.data, self.state[i], INTEGRATION)
        self.start[i] = physics.step_start
        self.warnings[i] = physics.data.warning.number

    def row_data(self, i: int) -> RowData:
        """Simulation i's fields as an MjData-like object (views of this batch's arrays)."""
        data = self._row_data[i]
        if data is None:
            data = self._row_data[i] = RowData(self, i)
        return data

    def row(self, i: int) -> RowPhysics:
        """Simulation i as a backend of one env (N = 1), views of this batch's arrays."""
        return RowPhysics(self, i)

    def unload(self, i: int, physics: PhysicsState) -> None:
        """Write row i into `physics`'s MjData, derived fields included (its last step is
        replayed from the row it started from)."""
        physics.adopt(self.start[i], self.state[i], self.warnings[i])


class RowData:
    """MjData-like access to one simulation of a `BatchPhysics`: `row.qpos` is row i of the
    batch's (N, nq) array (writable for state fields such as `xfrc_applied` and `eq_active`,
    read-only for derived ones). Only fields bound by the batch (its `fields`) exist."""

    def __init__(self, physics: BatchPhysics, i: int):
        self._fields = {name: physics.field(name)[i] for name in physics.field_names}
        self._batch, self._ids = physics.batch, [i]

    def ray(self, origin: np.ndarray, directions: np.ndarray, groups: np.ndarray):
        """(distances, geom ids) of rays from `origin` along `directions` (nray, 3) in this
        simulation, geoms of `groups` only (MuJoCo's batch rays: -1 for a miss)."""
        dist, geoms = self._batch.ray(origin, directions, groups, ids=self._ids)
        return dist[0], geoms[0]

    def __getattr__(self, name: str) -> np.ndarray:
        try:
            return self._fields[name]
        except KeyError:
            raise AttributeError(f"field {name!r} is not bound by this batch") from None


class RowPhysics:
    """Simulation i of a `BatchPhysics` as the backend of one env (N = 1): what a sub-env's
    per-env rules (Parkour's water, grasps and creepers) read and write between batch steps;
    `data` is a `RowData`, `model` the sub-env's own model. It does not step: the batch does."""

    def __init__(self, physics: BatchPhysics, i: int):
        self.model = physics.models[i]
        self.models = [self.model]
        self.data = physics.row_data(i)
        self.controls = physics.controls[i : i + 1]
        self.warnings = physics.warnings[i : i + 1]
        self._fields = {name: physics.field(name)[i : i + 1] for name in physics.field_names}

    def field(self, name: str) -> np.ndarray:
        """Live (1, ...) array of a bound MjData field."""
        return self._fields[name]

    def set_force_caps(self, index, ranges: np.ndarray) -> None:
        self.model.actuator_forcerange[index] = ranges[0]

    def row_data(self, i: int) -> RowData:
        return self.data
