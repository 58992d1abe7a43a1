"""Lightning callbacks: periodic held-out evaluation and an iteration progress bar with rate and ETA."""

from __future__ import annotations

import lightning as L
from tqdm.auto import tqdm

from vitac.rl.evaluation import run_episodes


class EvaluationCallback(L.Callback):
    """Every `every` iterations, run the deterministic policy on `episodes` held-out seeded episodes.

    Args:
        make_envs: builds the evaluation vector env (called once, lazily).
        every: iterations between evaluations.
        episodes: episodes per evaluation.
        seed: first evaluation seed (held out from the training seeds).
    """

    def __init__(self, make_envs, every: int, episodes: int, seed: int = 1_000_000):
        self.make_envs, self.every, self.episodes, self.seed = make_envs, every, episodes, seed
        self.envs = None
        self.last = None

    def on_train_epoch_end(self, trainer, module):
        iteration = trainer.current_epoch + 1
        if iteration % self.every and iteration != trainer.max_epochs:
            return
        if self.envs is None:
            self.envs = self.make_envs()
        summary = run_episodes(module.policy, self.envs, self.episodes, self.seed)
        self.last = summary
        metrics = {"eval/success_rate": summary["success_rate"]}
        if summary["steps_to_success_mean"] is not None:
            metrics["eval/steps_to_success"] = summary["steps_to_success_mean"]
        module.log_dict(metrics, on_epoch=True)

    def teardown(self, trainer, module, stage):
        if self.envs is not None:
            self.envs.close()


class IterationProgressBar(L.Callback):
    """One bar over all iterations showing env steps/s, success rate and ETA."""

    def on_train_start(self, trainer, module):
        self.bar = tqdm(total=trainer.max_epochs, initial=trainer.current_epoch, desc="PPO", unit="it",
                        dynamic_ncols=True)

    def on_train_epoch_end(self, trainer, module):
        m = trainer.callback_metrics
        postfix = {"env_steps": int(module.env_steps), "SPS": f"{float(m.get('charts/SPS', 0)):.0f}",
                   "success": f"{float(m.get('charts/success_rate', float('nan'))):.2f}"}
        if "eval/success_rate" in m:
            postfix["eval"] = f"{float(m['eval/success_rate']):.2f}"
        self.bar.set_postfix(postfix)
        self.bar.update(1)

    def on_train_end(self, trainer, module):
        self.bar.close()
