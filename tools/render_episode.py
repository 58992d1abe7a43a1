"""Render one episode to a video: outside view, wrist view, and both pads' force fields (arrows for shear
over a heatmap of normal force), side by side as in the paper's force-field figure.

    python tools/render_episode.py --out docs/media/oracle_episode.gif            # scripted oracle
    python tools/render_episode.py --ckpt outputs/.../checkpoints/last.ckpt --out episode.mp4

The right pad's map is shown flipped vertically, so a balanced grasp looks like two matching maps.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from vitac.envs.gym_env import InsertionEnv  # first: it selects headless EGL before mujoco loads

OUTSIDE = 240


def frame_image(fig, axes, outside, wrist, left, right, step, info):
    import matplotlib.pyplot as plt  # noqa: F401

    for ax in axes:
        ax.clear()
        ax.axis("off")
    axes[0].imshow(outside)
    axes[0].set_title(f"step {step}  kp dist {1000 * info['keypoint_distance']:.1f} mm", fontsize=8)
    axes[1].imshow(wrist)
    axes[1].set_title("wrist 64x64", fontsize=8)
    vmax = max(float(np.abs(left[2]).max()), float(np.abs(right[2]).max()), 1e-6)
    for ax, field, name in ((axes[2], left, "left pad"), (axes[3], right[:, ::-1], "right pad (flipped)")):
        ax.imshow(field[2], cmap="magma", vmin=0, vmax=vmax)
        rows, cols = np.mgrid[0:field.shape[1]:3, 0:field.shape[2]:3]
        ax.quiver(cols, rows, field[1][::3, ::3], field[0][::3, ::3], color="cyan", scale=None)
        ax.set_title(name, fontsize=8)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ckpt", default=None, help="policy checkpoint (default: the scripted oracle)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--every", type=int, default=3, help="render every k-th control step")
    parser.add_argument("--out", type=Path, default=Path("episode.gif"))
    args = parser.parse_args()

    import imageio.v2 as imageio
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import mujoco
    import torch

    observations = ["proprio", "wrist", "tactile_left", "tactile_right", "peg_state", "contact_forces", "critic_state"]
    policy = None
    if args.ckpt:
        from vitac.evaluate import load_policy

        policy, _, settings = load_policy(args.ckpt)
        config = dict(settings, observations=observations)
    else:
        config = {"observations": observations}
    env = InsertionEnv(config, seed=args.seed, offscreen_size=OUTSIDE)
    obs, info = env.reset(seed=args.seed)
    outside = mujoco.Renderer(env.physics.model.ptr, OUTSIDE, OUTSIDE)
    oracle = None
    if policy is None:
        from vitac.envs.oracle import OracleController

        oracle = OracleController(env.task)
    state, starts = (policy.initial_state(1), torch.ones(1)) if policy is not None else (None, None)
    fig, axes = plt.subplots(1, 4, figsize=(12, 3.2), dpi=80)
    frames, step, done = [], 0, False
    while not done:
        if step % args.every == 0:
            outside.update_scene(env.physics.data.ptr, "outside")
            raw = env.task.raw_tactiles(env.physics)
            frames.append(frame_image(fig, axes, outside.render(), obs["wrist"].transpose(1, 2, 0), raw[0], raw[1],
                                      step, info))
        if policy is None:
            action = oracle(env.physics)
        else:
            with torch.no_grad():
                obs_t = {k: torch.as_tensor(v)[None, None] for k, v in obs.items()}
                mean, _, _, state = policy(obs_t, state, starts[None])
            action, starts = mean[0, 0].numpy(), torch.zeros(1)
        obs, _, terminated, truncated, info = env.step(np.clip(action, -1, 1))
        done, step = terminated or truncated, step + 1
    outside.close()
    env.close()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if args.out.suffix == ".gif":
        imageio.mimsave(args.out, frames, duration=args.every / 60.0, loop=0)
    else:
        imageio.mimsave(args.out, frames, fps=60 / args.every)
    print(f"{args.out}: {len(frames)} frames, success={info['success']}, steps to succeed={info['steps_to_success']}")


if __name__ == "__main__":
    main()
