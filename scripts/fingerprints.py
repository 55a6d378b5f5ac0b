"""Determinism fingerprints: a hash of a fixed rollout per environment and body.

A refactor of the env core must leave every fingerprint unchanged (issue: "one env core").
`python scripts/fingerprints.py --write` records them into tests/data/fingerprints.json;
`python scripts/fingerprints.py` recomputes them and lists the ones that changed.
The rollout: seed 0, a fixed non-default task, 300 steps of seeded uniform random actions,
a second episode after the first ends; the hash covers observations, rewards, flags and the
terrain heights.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

import acl3d  # noqa: F401  (registers the ids)
from acl3d.bodies import BODIES
from acl3d.envs import make

FINGERPRINTS = Path(__file__).resolve().parents[1] / "tests" / "data" / "fingerprints.json"
STEPS = 300
TASKS = {
    "stump-tracks": {"stump_height": 1.0, "obstacle_spacing": 2.0},
    "hexagon-tracks": {"poly_shape": [1.0] * 12},
    "parkour": {"input_vector": [0.2, -0.3, 0.1], "water_level": 0.3, "creepers_height": 2.0},
    "terrain3d": {
        "block_height": 0.6,
        "block_width": 0.4,
        "block_spacing": 2.0,
        "cross_slope": 12.0,
        "hill_slope": 8.0,
        "roughness": 0.15,
    },
}
# Every body on Stump Tracks; the three body kinds on the other tracks; a 3D and a planar
# walker on 3D Terrain.
CASES = [("stump-tracks", body) for body in BODIES] + [
    ("hexagon-tracks", "classic_bipedal"),
    ("parkour", "classic_bipedal"),
    ("parkour", "climbing_profile_chimpanzee"),
    ("parkour", "fish"),
    ("terrain3d", "big_quadru"),
    ("terrain3d", "classic_bipedal"),
]


def fingerprint(env_name: str, body: str) -> str:
    """SHA-256 of a fixed rollout's observations, rewards, flags and terrain."""
    env = make(env_name, body=body)
    actions = np.random.default_rng(1234)
    digest = hashlib.sha256()
    obs, _ = env.reset(seed=0, options={"task": TASKS[env_name]})
    digest.update(np.ascontiguousarray(obs).tobytes())
    for hfield in np.asarray(env.unwrapped.model.hfield_data, dtype=np.float32)[None]:
        digest.update(hfield.tobytes())
    for _ in range(STEPS):
        action = actions.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        obs, reward, terminated, truncated, _ = env.step(action)
        digest.update(np.ascontiguousarray(obs).tobytes())
        digest.update(np.float64(reward).tobytes())
        digest.update(bytes([terminated, truncated]))
        if terminated or truncated:
            obs, _ = env.reset()
            digest.update(np.ascontiguousarray(obs).tobytes())
    env.close()
    return digest.hexdigest()


def compute() -> dict[str, str]:
    return {f"{env}/{body}": fingerprint(env, body) for env, body in CASES}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="record the current fingerprints")
    args = parser.parse_args()
    current = compute()
    if args.write:
        FINGERPRINTS.parent.mkdir(parents=True, exist_ok=True)
        FINGERPRINTS.write_text(json.dumps(current, indent=1, sort_keys=True) + "\n")
        print(f"wrote {len(current)} fingerprints to {FINGERPRINTS}")
        return 0
    recorded = json.loads(FINGERPRINTS.read_text())
    changed = sorted(k for k in recorded if recorded[k] != current.get(k))
    for key in changed:
        print(f"changed: {key}")
    print(f"{len(recorded) - len(changed)} of {len(recorded)} fingerprints unchanged")
    return 1 if changed else 0


if __name__ == "__main__":
    sys.exit(main())
