"""Gallery of every body on Stump Tracks: a PNG and a short mp4 each, a contact sheet, and a table.

For each body (in its default mode: planar or 3D) it renders the spawn pose as a PNG and a short
clip of the open-loop gait used by the tests (1 Hz sine per action entry, a quarter period apart),
then measures env steps/s in both modes with uniform random actions. The markdown table (body,
type, DoF, action size, observation sizes, torque, default mode, steps/s) is printed and written
to OUT/bodies.md. Timings depend on the machine and its load; compare rows of one run only.

    python scripts/gallery.py --out /tmp/gallery
    python scripts/gallery.py --out /tmp/gallery --bodies spider,fish --seconds 2 --rate-steps 500
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import imageio.v2 as imageio
import matplotlib
import numpy as np

import acl3d  # noqa: F401  (first: picks the headless GL backend, registers the environments)
from acl3d.bodies import BODIES

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

TASK = {"stump_height": 1.0, "obstacle_spacing": 3.0}
FPS = 25  # video frame rate: one frame every two 50 Hz control steps
ENV_ID = "acl3d/StumpTracks-v0"


def gait(t: int, n: int) -> np.ndarray:
    """The tests' open-loop gait: a 1 Hz sine per action entry, a quarter period apart."""
    return np.sin(2 * np.pi * t / 50 + np.pi / 2 * np.arange(n))


def render_body(name: str, out: Path, seconds: float, width: int, height: int) -> np.ndarray:
    """Write NAME.png (spawn pose) and NAME.mp4 (gait clip); return the PNG image."""
    env = gym.make(ENV_ID, body=name, render_mode="rgb_array", width=width, height=height)
    env.reset(seed=0, options={"task": TASK})
    image = env.render()
    stem = name.replace(":", "_")
    imageio.imwrite(out / f"{stem}.png", image)
    frames = []
    n = env.action_space.shape[0]
    for t in range(int(seconds * 50)):
        env.step(gait(t, n))  # keeps stepping after a termination: this is a film, not an episode
        if t % (50 // FPS) == 0:
            frames.append(env.render())
    imageio.mimwrite(out / f"{stem}.mp4", frames, fps=FPS, macro_block_size=8)
    env.close()
    return image


def steps_per_second(name: str, planar: bool, steps: int) -> float:
    """env.step rate with uniform random actions; resets (on termination) are not timed."""
    env = gym.make(ENV_ID, body=name, planar=planar).unwrapped
    env.reset(seed=0, options={"task": TASK})
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, env.action_space.shape[0]))
    elapsed = 0.0
    for a in actions:
        t0 = time.perf_counter()
        _, _, terminated, _, _ = env.step(a)
        elapsed += time.perf_counter() - t0
        if terminated:
            env.reset()
    return steps / elapsed


def describe(name: str, rate_steps: int) -> dict:
    envs = {p: gym.make(ENV_ID, body=name, planar=p).unwrapped for p in (True, False)}
    body = envs[True].body
    gears = envs[True].model.actuator_gear[envs[True].bound.actuator_ids, 0]
    caps = body.torque * gears  # joint torque at |a| = 1 (dm_control walkers: per joint)
    torque = f"{caps.min():g}" if caps.min() == caps.max() else f"{caps.min():g}-{caps.max():g}"
    return {
        "body": name,
        "type": body.kind,
        "dof": envs[True].model.nv - 3,  # joints of the body, planar root excluded
        "actions": body.action_size,
        "obs": f"{envs[True].rules.obs_size} / {envs[False].rules.obs_size}",
        "torque": torque,
        "default": "planar" if body.planar_default else "3D",
        "rate": f"{steps_per_second(name, True, rate_steps):,.0f} / "
        f"{steps_per_second(name, False, rate_steps):,.0f}",
    }


def table(rows: list[dict]) -> str:
    head = (
        "| body | type | DoF | actions | obs (planar / 3D) | torque | default | "
        "env steps/s (planar / 3D) |\n|---|---|---|---|---|---|---|---|\n"
    )
    return head + "".join(
        f"| {r['body']} | {r['type']} | {r['dof']} | {r['actions']} | {r['obs']} | {r['torque']} "
        f"| {r['default']} | {r['rate']} |\n"
        for r in rows
    )


def contact_sheet(images: dict[str, np.ndarray], path: Path, columns: int = 4) -> None:
    rows = -(-len(images) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4 * columns, 3.1 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, (name, image) in zip(axes.ravel(), images.items()):
        ax.imshow(image)
        ax.set_title(name, fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--out", required=True, type=Path, help="output directory (created)")
    p.add_argument("--bodies", default="all", help="comma-separated names, or 'all'")
    p.add_argument("--seconds", type=float, default=4.0, help="clip length, simulated seconds")
    p.add_argument("--rate-steps", type=int, default=2000, help="random steps per speed test")
    p.add_argument("--width", type=int, default=480)
    p.add_argument("--height", type=int, default=360)
    args = p.parse_args()
    names = list(BODIES) if args.bodies == "all" else args.bodies.split(",")
    unknown = [n for n in names if n not in BODIES]
    if unknown:
        raise SystemExit(f"unknown bodies {unknown}; valid: {', '.join(BODIES)}")
    if args.seconds <= 0 or args.rate_steps < 1:
        raise SystemExit("--seconds must be > 0 and --rate-steps >= 1")
    args.out.mkdir(parents=True, exist_ok=True)

    images, rows = {}, []
    for name in names:
        images[name] = render_body(name, args.out, args.seconds, args.width, args.height)
        rows.append(describe(name, args.rate_steps))
        print(f"{name}: {rows[-1]['rate']} steps/s (planar / 3D)", flush=True)
    contact_sheet(images, args.out / "contact_sheet.png")
    text = table(rows)
    (args.out / "bodies.md").write_text(text)
    print("\n" + text)
    print(f"PNGs, mp4s, contact_sheet.png and bodies.md in {args.out}")


if __name__ == "__main__":
    main()
