"""Several worker processes, each stepping a batched env: one SB3 `VecEnv` for machines with
more cores than one process's physics threads use well.

Worker w runs a `BatchedVecEnv` of its own sub-envs (global index = offset of w + local
index); one message per worker per step carries all its actions and results. `env_method`,
`get_attr` and `set_attr` go to the right worker's `SubEnv`, so `CurriculumVecEnv` keeps every
sub-env's task queue filled (pushing mode) exactly as with one env per process. Workers are
started with `forkserver` or `spawn` (never `fork`: MuJoCo rendering and torch threads).
"""

from __future__ import annotations

import multiprocessing as mp
import traceback

import numpy as np

from acl3d.extras import optional_dependency

with optional_dependency("the batched env's worker processes"):
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv


class WorkerCrash(RuntimeError):
    """A batched worker process raised; the message carries its traceback."""


def _worker(remote, parent_remote, factory) -> None:
    parent_remote.close()
    venv = None
    try:
        venv = factory()
        remote.send(("ok", (venv.num_envs, venv.observation_space, venv.action_space)))
        while True:
            cmd, data = remote.recv()
            try:
                if cmd == "step":
                    venv.step_async(data)
                    result = venv.step_wait()
                elif cmd == "reset":
                    venv._seeds, venv._options = data
                    result = (venv.reset(), venv.reset_infos)
                elif cmd == "env_method":
                    name, args, kwargs, indices = data
                    result = venv.env_method(name, *args, indices=indices, **kwargs)
                elif cmd == "get_attr":
                    result = venv.get_attr(*data)
                elif cmd == "set_attr":
                    result = venv.set_attr(*data)
                elif cmd == "close":
                    remote.send(("ok", None))
                    break
                else:
                    raise ValueError(f"unknown command {cmd!r}")
            except Exception:
                remote.send(("error", traceback.format_exc()))
                continue
            remote.send(("ok", result))
    except (EOFError, KeyboardInterrupt):
        pass
    except Exception:
        remote.send(("error", traceback.format_exc()))
    finally:
        if venv is not None:
            venv.close()


class BatchedSubprocVecEnv(VecEnv):
    """`factories[w]()` builds worker w's `BatchedVecEnv`; sub-envs are numbered worker by worker."""

    def __init__(self, factories, start_method: str = "forkserver"):
        ctx = mp.get_context(start_method)
        self.remotes, self.processes = [], []
        for factory in factories:
            remote, work_remote = ctx.Pipe()
            process = ctx.Process(target=_worker, args=(work_remote, remote, factory), daemon=True)
            process.start()
            work_remote.close()
            self.remotes.append(remote)
            self.processes.append(process)
        self.closed = False
        specs = [self._receive(r) for r in self.remotes]
        sizes = [s[0] for s in specs]
        self.offsets = np.concatenate(([0], np.cumsum(sizes))).astype(int)
        super().__init__(int(self.offsets[-1]), specs[0][1], specs[0][2])  # asks render_mode

    def _receive(self, remote):
        try:
            status, payload = remote.recv()
        except (EOFError, ConnectionError) as exc:
            codes = [p.exitcode for p in self.processes]
            self.close()
            raise WorkerCrash(f"a batched worker process died (exit codes {codes})") from exc
        if status == "error":
            self.close()
            raise WorkerCrash(f"a batched worker process crashed:\n{payload}")
        return payload

    def _by_worker(self, indices):
        """{worker: [local indices]} for global `indices`, workers in order."""
        groups: dict[int, list[int]] = {}
        for i in self._get_indices(indices):
            w = int(np.searchsorted(self.offsets, i, side="right") - 1)
            groups.setdefault(w, []).append(int(i - self.offsets[w]))
        return groups

    def _call(self, cmd: str, make_data, indices) -> list:
        groups = self._by_worker(indices)
        for w, local in groups.items():
            self.remotes[w].send((cmd, make_data(local)))
        out: list = []
        for w in groups:
            out.extend(self._receive(self.remotes[w]))
        return out

    # ------------------------------------------------------------------ VecEnv
    def reset(self):
        seeds, options = self._seeds, self._options
        for w, remote in enumerate(self.remotes):
            lo, hi = self.offsets[w], self.offsets[w + 1]
            remote.send(("reset", (seeds[lo:hi] if seeds else [], options[lo:hi])))
        results = [self._receive(r) for r in self.remotes]
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [info for _, infos in results for info in infos]
        return np.concatenate([obs for obs, _ in results])

    def step_async(self, actions) -> None:
        actions = np.asarray(actions)
        for w, remote in enumerate(self.remotes):
            remote.send(("step", actions[self.offsets[w] : self.offsets[w + 1]]))

    def step_wait(self):
        results = [self._receive(r) for r in self.remotes]
        obs, rewards, dones, infos = zip(*results)
        flat_infos = [info for chunk in infos for info in chunk]
        return np.concatenate(obs), np.concatenate(rewards), np.concatenate(dones), flat_infos

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        return self._call(
            "env_method", lambda local: (method_name, method_args, method_kwargs, local), indices
        )

    def get_attr(self, attr_name, indices=None):
        return self._call("get_attr", lambda local: (attr_name, local), indices)

    def set_attr(self, attr_name, value, indices=None) -> None:
        groups = self._by_worker(indices)
        for w, local in groups.items():
            self.remotes[w].send(("set_attr", (attr_name, value, local)))
        for w in groups:
            self._receive(self.remotes[w])

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False for _ in self._get_indices(indices)]

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for remote in self.remotes:
            try:
                remote.send(("close", None))
                remote.recv()
            except (BrokenPipeError, EOFError, ConnectionResetError):
                pass
        for process in self.processes:
            process.join(timeout=10)
            if process.is_alive():
                process.terminate()
