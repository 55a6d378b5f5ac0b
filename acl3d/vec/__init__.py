"""Stable-Baselines3 vector envs over acl3d's batched env: the layer between `acl3d.envs`
(Gymnasium only, no SB3) and `acl3d.training`.

* `batched_sb3.BatchedVecEnv`: N sub-envs in this process as an SB3 `VecEnv`, each sub-env a
  curriculum worker (`acl3d.envs.curriculum_wrapper.TaskQueue`);
* `batched_workers.BatchedSubprocVecEnv`: several worker processes, each stepping one.
"""
