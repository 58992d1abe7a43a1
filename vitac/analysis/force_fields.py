"""The left and right force fields over one held-out episode, for several policies: the paper's Fig. "qual".

Each policy runs the same episode (same seed); at evenly spaced steps the figure shows the left pad's normal
force field above the right pad's mirrored into the left pad's frame (`vitac.models.symmetry.mirror_pad`), so a
bilaterally symmetric grasp shows two equal maps, and below them the left-right imbalance over the whole
episode: each step's field asymmetry (vitac/sim/balance.py, every channel; the measure the evaluation reports
carry), with the episode's mean in the legend. The fields are the residuals the policy sees
(paper eq. 2: the field minus the one at grasp), negative where a pad presses less than at the grasp, so they
are drawn on a diverging scale centred on zero (red: more pressure than at grasp, blue: less).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

NORMAL = 2  # the force field's channels: shear_x, shear_y, normal


def record_fields(ckpt: str, seed: int) -> dict:
    """One deterministic episode of the checkpoint's policy: every step's left and mirrored right normal fields and
    its field asymmetry (None where neither pad feels anything)."""
    from vitac.envs.gym_env import TaskEnv
    from vitac.models.symmetry import mirror_pad
    from vitac.run_config import load_policy
    from vitac.sim.balance import step_asymmetries
    from vitac.viz import policy_actor

    policy, _, settings = load_policy(ckpt)
    observations = sorted(set(policy.input_keys) | {"tactile_left", "tactile_right"})
    env = TaskEnv(dict(settings, observations=observations), seed=seed)
    act = policy_actor(policy.eval())
    obs, info = env.reset(seed=seed)
    left, right, asym, done = [], [], [], False
    try:
        while not done:
            left.append(obs["tactile_left"][NORMAL])
            right.append(mirror_pad(torch.as_tensor(obs["tactile_right"])).numpy()[NORMAL])
            asym.append(step_asymmetries(obs["tactile_left"], obs["tactile_right"])["field"])
            obs, _, terminated, truncated, info = env.step(np.clip(act(obs), -1.0, 1.0))
            done = terminated or truncated
    finally:
        env.close()
    return dict(left=np.array(left), right=np.array(right), asymmetry=asym, success=bool(info["success"]))


def figure(episodes: dict[str, dict], out: Path, columns: int = 6) -> Path:
    """A grid of the policies' fields (two rows each: left, mirrored right) at `columns` steps, and the imbalance."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = 2 * len(episodes) + 1
    fig, axes = plt.subplots(rows, columns, figsize=(1.6 * columns, 1.5 * rows), squeeze=False)
    peak = max(float(np.abs(np.concatenate([e["left"], e["right"]])).max()) for e in episodes.values()) or 1.0
    for p, (name, episode) in enumerate(episodes.items()):
        steps = np.linspace(0, len(episode["left"]) - 1, columns).astype(int)
        for c, step in enumerate(steps):
            for r, side in enumerate(("left", "right")):
                ax = axes[2 * p + r, c]
                image = ax.imshow(episode[side][step], cmap="RdBu_r", vmin=-peak, vmax=peak)
                ax.set_xticks([])
                ax.set_yticks([])
                if c == 0:
                    ax.set_ylabel(f"{name}\n{'left' if r == 0 else 'right, mirrored'}", fontsize=7)
                if p == 0 and r == 0:
                    ax.set_title(f"step {step}", fontsize=8)
    fig.colorbar(image, ax=axes[:-1].ravel().tolist(), shrink=0.6, label="normal residual (eq. 2)")
    gs = axes[-1, 0].get_gridspec()
    for ax in axes[-1]:
        ax.remove()
    imbalance = fig.add_subplot(gs[-1, :])
    for name, episode in episodes.items():
        asym = np.array([np.nan if a is None else a for a in episode["asymmetry"]])  # gaps: neither pad touched
        mean = f"mean {np.nanmean(asym):.2f}" if np.isfinite(asym).any() else "no touch"
        imbalance.plot(asym, label=f"{name} ({'inserted' if episode['success'] else 'not inserted'}; {mean})")
    imbalance.set(xlabel="control step", ylabel="field asymmetry", ylim=(0, 1))
    imbalance.legend(fontsize=7)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
