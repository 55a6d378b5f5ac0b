"""One simulation of many worlds: one compiled model, N worlds, the per-world quantities declared.

An env family (tracks, Parkour, 3D Terrain) composes its model once; the worlds differ only in the
quantities its `WorldFields` declares (terrain heightfields, servo force caps, ...). A backend steps
all worlds together and exposes their state as live (N, ...) torch tensors, so the rules run on
whole batches with no per-world Python:

* `acl3d.sim.worlds`: `WorldFields` (what differs between worlds) and the `Simulation` protocol
  every backend implements;
* `acl3d.sim.warp_backend`: MuJoCo Warp (CUDA, or Warp's CPU device for tests), needs the `[gpu]`
  extra;
* `acl3d.sim.graphed`: torch work replayed as CUDA graphs (a reset's small operations as one
  launch).

The CPU path steps its sub-envs' own models on MuJoCo's native batch (`mujoco.batch`, C
threads): `acl3d.envs.physics.BatchPhysics`, behind `acl3d.envs.batched`.
"""
