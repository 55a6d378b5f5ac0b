"""Any Stable-Baselines3 algorithm as the student of an acl3d curriculum run, with its own
hyperparameters: TD3 through `train()` (named "sb3:TD3", or pass the class), A2C through the
command line.

    python scripts/examples/sb3_any_algorithm.py --steps 50000 --out runs/any_sb3

Needs `pip install "acl3d[train]"` (Stable-Baselines3 and torch).

The preset sets only the network (`fast`: 64-64); every other hyperparameter is the algorithm's
own default unless given (`student_params` / `--student-param`, checked against the
algorithm's constructor). `action_noise_std` gives TD3 / DDPG Gaussian exploration noise. The
run directory, evaluations, exact resume and `acl3d evaluate` work as for SAC and PPO.
Algorithms from other packages: `student="package.module:Class"` (any `BaseAlgorithm`).
"""

from __future__ import annotations

import argparse

from stable_baselines3 import TD3

from acl3d.cli import main as acl3d_main
from acl3d.training import train


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=50_000)
    p.add_argument("--out", default="runs/any_sb3")
    p.add_argument("--max-episode-steps", type=int, default=2000)
    p.add_argument("--learning-starts", type=int, default=10_000, help="TD3's")
    args = p.parse_args(argv)
    td3 = train(
        env="stump-tracks",
        teacher="alp-gmm",
        student=TD3,  # or "sb3:TD3"
        preset="fast",
        n_envs=4,
        steps=args.steps,
        student_params={
            "learning_starts": args.learning_starts,
            "action_noise_std": 0.1,
            "batch_size": 256,
            "gamma": 0.98,
        },
        env_kwargs={"max_episode_steps": args.max_episode_steps},
        test_set="uniform",
        nb_test_episodes=4,
        tensorboard=False,
        progress_bar=False,
        out=args.out + "/td3",
    )
    print(f"TD3: {td3.steps} steps, final evaluation {td3.final_eval}")
    rc = acl3d_main(
        ["train", "--student", "sb3:A2C", "--student-param", "n_steps=16",
         "--student-param", "learning_rate=0.0007", "--teacher", "random", "--env", "stump-tracks",
         "--preset", "fast", "--n-envs", "4", "--steps", str(args.steps), "--env-kwarg",
         f"max_episode_steps={args.max_episode_steps}", "--test-set", "uniform",
         "--nb-test-episodes", "4", "--no-tensorboard", "--no-progress", "--quiet",
         "--out", args.out + "/a2c"]
    )  # fmt: skip
    return td3, rc


if __name__ == "__main__":
    main()
