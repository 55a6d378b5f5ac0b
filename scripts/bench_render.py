"""Rendering speed at 640x480 and what labels and video files add, in one run.

Every row is measured in this run on the same env and the same random actions (in interleaved
rounds, keeping each row's best), and printed with its ratio to plain step + render, so the
overlay's cost reads as a share of a frame:

    python scripts/bench_render.py [--frames 400] [--width 640 --height 480]
    python scripts/bench_render.py --env terrain3d --quality high

Rows: render only; step + render; step + render + label (acl3d.overlay); the label alone;
step + render + label + H.264 encoding (what `acl3d render` does per frame).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import gymnasium as gym
import numpy as np
from bench_terrain3d import TASK as TERRAIN3D_TASK  # scripts/ is on sys.path: a sibling script

import acl3d  # noqa: F401  (first: picks the headless GL backend before mujoco loads)
from acl3d.envs import ENV_IDS
from acl3d.overlay import draw_label, episode_lines
from acl3d.video import VideoSink

TASKS = {  # 3D Terrain: bench_terrain3d's task (blocks, twist, hills and bumps in view)
    "stump-tracks": {"stump_height": 1.0, "obstacle_spacing": 3.0},
    "terrain3d": TERRAIN3D_TASK,
}


def _timed(frames: int, per_frame) -> float:
    """Frames per second of `per_frame(frame_index)` over `frames` frames (after a warm-up)."""
    per_frame(-1)
    t0 = time.perf_counter()
    for i in range(frames):
        per_frame(i)
    return frames / (time.perf_counter() - t0)


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--frames", type=int, default=600, help="frames per case, over all rounds")
    p.add_argument("--rounds", type=int, default=6)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--env", choices=sorted(TASKS), default="stump-tracks")
    p.add_argument("--quality", choices=("fast", "high"), default="fast")
    args = p.parse_args()
    task = TASKS[args.env]
    env = gym.make(
        ENV_IDS[args.env],
        render_mode="rgb_array",
        width=args.width,
        height=args.height,
        quality=args.quality,
    )
    env.reset(seed=0, options={"task": task})
    rng = np.random.default_rng(0)
    lines = episode_lines("run (alp-gmm)", task, 123, 45.6)
    frame = env.render()

    def step(_):
        action = rng.uniform(-1, 1, env.action_space.shape)
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()

    def step_render(i):
        step(i)
        return env.render()

    def step_render_label(i):
        draw_label(step_render(i), lines)

    with tempfile.TemporaryDirectory() as tmp:
        sink = VideoSink(os.path.join(tmp, "bench.mp4"), fps=50)

        def step_render_label_encode(i):
            frame = step_render(i)
            sink.append(draw_label(frame, lines))

        cases = {
            "render only": lambda i: env.render(),
            "step + render": step_render,
            "step + render + label": step_render_label,
            "label only": lambda i: draw_label(frame.copy(), lines),
            "step + render + label + mp4": step_render_label_encode,
        }
        best = dict.fromkeys(cases, 0.0)
        for _ in range(args.rounds):  # interleaved rounds, best of each: robust to other load
            for name, case in cases.items():
                best[name] = max(best[name], _timed(args.frames // args.rounds, case))
        rows = list(best.items())
        sink.close()
    env.close()
    base = rows[1][1]
    print(
        f"{args.env}, {args.width}x{args.height}, {args.quality} preset, "
        f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}"
    )
    for name, fps in rows:
        print(f"{name:30s} {fps:9.1f} fps  {1e3 / fps:7.3f} ms/frame  {fps / base:5.2f}x")
    label_ms = 1e3 / rows[2][1] - 1e3 / rows[1][1]
    print(f"label cost: {label_ms:.3f} ms/frame = {100 * label_ms * base / 1e3:.1f}% of a frame")


if __name__ == "__main__":
    main()
