"""Episode videos: outside view, wrist view, and both pads' raw force fields (shear arrows over normal force, which
is never negative; the policy sees them minus the fields at grasp)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

OUTSIDE = 240  # pixels of the outside view (the env's offscreen buffer must be at least this big)
VIDEO_OBSERVATIONS = ["wrist", "tactile_left", "tactile_right"]


def _frame(fig, axes, outside, wrist, left, right, step: int, info: dict) -> np.ndarray:
    for ax in axes:
        ax.clear()
        ax.axis("off")
    axes[0].imshow(outside)
    axes[0].set_title(f"step {step}  keypoint dist {1000 * info['keypoint_distance']:.1f} mm", fontsize=8)
    axes[1].imshow(wrist)
    axes[1].set_title("wrist 64x64", fontsize=8)
    vmax = max(float(np.abs(left[2]).max()), float(np.abs(right[2]).max()), 1e-6)
    for ax, field, name in ((axes[2], left, "left pad, raw"), (axes[3], right[:, ::-1], "right pad, raw (rows flipped)")):
        ax.imshow(field[2], cmap="magma", vmin=0, vmax=vmax)
        rows, cols = np.mgrid[0:field.shape[1]:3, 0:field.shape[2]:3]
        shear = field[:2, ::3, ::3]  # every third taxel
        if np.any(shear):  # quiver's autoscale divides by the mean arrow: none to draw at the grasp reference
            ax.quiver(cols, rows, shear[1], shear[0], color="cyan")
        ax.set_title(name, fontsize=8)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def record_episode(env, act: Callable[[dict], np.ndarray], seed: int, every: int = 3) -> tuple[list, dict]:
    """Run one episode with `act(obs) -> action`, rendering every `every`-th control step.

    `env` is an TaskEnv built with `offscreen_size >= OUTSIDE` and the VIDEO_OBSERVATIONS enabled.
    Returns the RGB frames and the last step's info (success, steps to succeed).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import mujoco

    obs, info = env.reset(seed=seed)
    outside = mujoco.Renderer(env.physics.model.ptr, OUTSIDE, OUTSIDE)
    fig, axes = plt.subplots(1, 4, figsize=(12, 3.2), dpi=80)
    frames, step, done = [], 0, False
    try:
        while not done:
            if step % every == 0:
                outside.update_scene(env.physics.data.ptr, "outside")
                raw = env.task.raw_tactiles(env.physics)
                frames.append(_frame(fig, axes, outside.render(), obs["wrist"].transpose(1, 2, 0), raw[0], raw[1],
                                     step, info))
            obs, _, terminated, truncated, info = env.step(np.clip(act(obs), -1.0, 1.0))
            done, step = terminated or truncated, step + 1
    finally:
        outside.close()
        plt.close(fig)
    return frames, info


def policy_actor(policy) -> Callable[[dict], np.ndarray]:
    """Deterministic (mean) actions of a recurrent policy, carrying its state across calls."""
    import torch

    memory = {"state": policy.initial_state(1, policy.device), "starts": torch.ones(1)}

    @torch.inference_mode()
    def act(obs: dict) -> np.ndarray:
        obs_t, starts = policy.step_inputs({k: np.asarray(v)[None] for k, v in obs.items()}, memory["starts"])
        mean, _, _, memory["state"] = policy(obs_t, memory["state"], starts)
        memory["starts"] = torch.zeros(1)
        return mean[0, 0].cpu().numpy()

    return act


def save_video(frames: list, path: Path, every: int) -> Path:
    import imageio.v2 as imageio

    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".gif":
        imageio.mimsave(path, frames, duration=every / 60.0, loop=0)
    else:
        imageio.mimsave(path, frames, fps=60 / every)
    return path
