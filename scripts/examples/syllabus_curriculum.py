"""A Syllabus curriculum (syllabus-rl 0.7) choosing the tasks of acl3d's batched vector env.

    python scripts/examples/syllabus_curriculum.py --steps 20000

Needs `pip install "acl3d[syllabus]"` (syllabus-rl 0.7; `[train]` alone does not have it).

Syllabus describes a continuous task space with `BoxTaskSpace(gym.spaces.Box)`: acl3d's
`task_space.gym_space` is that Box. `SyllabusSync` is the batched env's curriculum sync (one
verb, `sync(finished, env_ids)`): `curriculum.update_on_episode(...)` for each finished
episode, then `curriculum.sample()` for the sub-envs that reset (after their episodes were told). Any Syllabus `Curriculum` over a Box fits; this
example uses `DomainRandomization` (uniform tasks) and random actions, and prints what was played.
No Syllabus multiprocessing wrappers are needed: everything runs in this process.
"""

from __future__ import annotations

import argparse

import numpy as np

import acl3d  # noqa: F401
from acl3d.envs.batched_vector import BatchedVectorEnv
from acl3d.extras import optional_dependency

# importing Syllabus 0.7 sets np.seterr(all="raise") for the whole process: errstate undoes it
with np.errstate(), optional_dependency("the Syllabus example"):
    from syllabus.curricula import DomainRandomization
    from syllabus.task_space import BoxTaskSpace


def domain_randomization(task_space, seed: int = 0) -> DomainRandomization:
    """Syllabus' uniform curriculum over an acl3d task space (seeded)."""
    box = BoxTaskSpace(task_space.gym_space)
    box.seed(seed)
    return DomainRandomization(box)


class SyllabusSync:
    """The batched env's `CurriculumSync` backed by a Syllabus `Curriculum`."""

    def __init__(self, curriculum):
        self.curriculum = curriculum

    def sync(self, finished, env_ids) -> np.ndarray:
        for k, index in enumerate(finished.env_ids):
            self.curriculum.update_on_episode(
                float(finished.returns[k]), int(finished.lengths[k]), finished.tasks[k],
                float(finished.successes[k]), int(index),
            )  # fmt: skip
        if not len(env_ids):
            return np.zeros((0, 0), dtype=np.float32)
        decode = self.curriculum.task_space.decode
        return np.array([decode(t) for t in self.curriculum.sample(k=len(env_ids))], np.float32)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="acl3d/StumpTracks-v0")
    p.add_argument("--num-envs", type=int, default=8)
    p.add_argument("--steps", type=int, default=20_000)
    p.add_argument("--max-episode-steps", type=int, default=None)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    kwargs = {} if args.max_episode_steps is None else {"max_episode_steps": args.max_episode_steps}
    probe = BatchedVectorEnv(args.env, 1, threads=1)
    curriculum = domain_randomization(probe.task_space, args.seed)
    probe.close()
    envs = BatchedVectorEnv(
        args.env, args.num_envs, curriculum_sync=SyllabusSync(curriculum), **kwargs
    )
    rng = np.random.default_rng(args.seed)
    envs.reset(seed=args.seed)
    tasks, returns = [], []
    for _ in range(args.steps // args.num_envs):
        *_, infos = envs.step(rng.uniform(-1, 1, envs.action_space.shape))
        for i in np.flatnonzero(infos.get("_curriculum", ())):
            tasks.append(infos["curriculum"][i]["task"])
            returns.append(infos["curriculum"][i]["return"])
    envs.close()
    tasks = np.array(tasks).reshape(-1, envs.task_space.dim)
    print(
        f"{len(tasks)} episodes on tasks from Syllabus' DomainRandomization; task means "
        f"{dict(zip(envs.task_space.flat_names(), tasks.mean(axis=0).round(2).tolist()))}, "
        f"mean return {np.mean(returns):.1f}"
    )
    return {"tasks": tasks, "returns": np.array(returns)}


if __name__ == "__main__":
    main()
