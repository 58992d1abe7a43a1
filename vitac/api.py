"""The short Python path: an environment and a shipped or trained policy in a few lines, and gymnasium ids.

    from vitac import load_policy, make_env

    policy = load_policy("cmt_sym_dagger")   # pretrained/cmt_sym_dagger.pt, or any checkpoint's path
    env = make_env(policy=policy)            # the task and observations it was trained with
    obs, info = env.reset(seed=2_000_000)
    policy.reset()
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs))
        done = terminated or truncated
    print(info["outcome"])

`make_env(task=<name>)` builds any task config of `conf/task/` as `python -m vitac.train task=<name>` trains on it,
and `gymnasium.make("vitac/PegInsertion-v0")` (or one of the other `GYM_IDS`) the same environments (registered on
`import vitac`), with the same keyword arguments as `make_env`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vitac.utils.checks import refuse

TASK_CONFIGS = Path(__file__).resolve().parents[1] / "conf" / "task"
GYM_IDS = {"vitac/PegInsertion-v0": "insertion", "vitac/NutScrew-v0": "screw",
           "vitac/NutScrewOffThread-v0": "screw_offthread", "vitac/NutInsertScrew-v0": "screw_insert"}


def task_names() -> list[str]:
    """The task configs a run or `make_env` can name: conf/task/<name>.yaml."""
    return sorted(path.stem for path in TASK_CONFIGS.glob("*.yaml"))


def task_settings(task: str = "insertion", **overrides) -> dict:
    """The settings of `conf/task/<task>.yaml` (with the configs it extends) as `python -m vitac.train task=<task>`
    composes them, `overrides` merged in key by key (`randomization={"scale": 0.5}` changes that key only)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    if task not in task_names():
        refuse("task", task, f"one of {task_names()} (conf/task/<name>.yaml)")
    with initialize_config_dir(version_base="1.3", config_dir=str(TASK_CONFIGS)):
        settings = OmegaConf.to_container(compose(task), resolve=True)
    return merged(settings, overrides)


def merged(settings: dict, overrides: dict) -> dict:
    """`settings` with `overrides` merged in key by key, nested dicts included."""
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.merge(settings, overrides))


class Policy:
    """A trained policy acting on one environment's observations: the deterministic (mean) action, carrying its
    recurrent state from step to step; `reset()` starts a new episode.

    Attributes:
        settings: the task settings it was trained with (what `make_env(policy=...)` builds).
        observations: the observations it reads (its own and, with a critic, the critic's).
    """

    def __init__(self, path: str):
        from vitac.run_config import load_policy as load_checkpoint_policy

        self.network, self.config, self.settings = load_checkpoint_policy(path)
        self.network.eval()
        self.observations = list(self.network.input_keys)
        self.reset()

    def reset(self) -> None:
        from vitac.viz import policy_actor

        self._act = policy_actor(self.network)

    def act(self, obs: dict) -> np.ndarray:
        """The action (6,) in [-1, 1] for one step's observation dict."""
        return np.clip(self._act(obs), -1.0, 1.0)


def load_policy(name: str) -> Policy:
    """A shipped policy by name (`"privileged"`, `"cmt_sym_dagger"`: `pretrained/<name>.pt`), or any checkpoint's
    path (`outputs/.../checkpoints/last.ckpt`)."""
    from vitac.utils.checkpoint import resolve_checkpoint

    path = name if "/" in str(name) or str(name).endswith((".pt", ".ckpt")) else f"pretrained/{name}"
    if not resolve_checkpoint(path).is_file():
        refuse("name", name, "a shipped policy's name (pretrained/<name>.pt) or a checkpoint file")
    return Policy(path)


def make_env(task: str = "insertion", observations: list | None = None, seed: int | None = None,
             policy: Policy | None = None, render_mode: str | None = None, **overrides):
    """A gymnasium environment of `task` (a config of conf/task: `insertion`, `screw`, `screw_offthread`,
    `screw_insert`) with `observations` (default: every one the task declares) and any task setting as a keyword
    (`peg_size=8`, `randomization={"scale": 0.5}`, merged into the config's); or, with
    `policy`, the environment that policy was trained with (its task, settings and observations; keywords merged
    into its settings the same way). `render()`
    gives the wrist camera's image (`render_mode="rgb_array"`, the only mode)."""
    from vitac.envs.gym_env import TaskEnv

    if render_mode not in (None, "rgb_array"):
        refuse("render_mode", render_mode, "None or 'rgb_array'")
    if policy is not None:
        settings = dict(merged(policy.settings, overrides), observations=policy.observations)
    else:
        settings = task_settings(task, **overrides)
        if observations is not None:
            settings["observations"] = list(observations)
    env = TaskEnv(settings, seed=seed)
    env.render_mode = render_mode
    return env


def register_gym_ids() -> None:
    """gymnasium ids for the tasks (`gymnasium.make("vitac/PegInsertion-v0", observations=[...])`)."""
    import gymnasium

    for gym_id, task in GYM_IDS.items():
        if gym_id not in gymnasium.registry:
            gymnasium.register(gym_id, entry_point="vitac.api:make_env", kwargs=dict(task=task))
