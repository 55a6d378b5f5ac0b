"""Torch-native students: their own training loop on a `TensorVectorEnv` (rsl_rl's PPO as
`rsl-ppo`), writing the run directory the SB3 students write."""
