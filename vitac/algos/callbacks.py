"""Lightning callbacks: periodic held-out evaluation and an iteration progress bar with rate and ETA."""

from __future__ import annotations

import os
import signal
import threading
from pathlib import Path

import lightning as L
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.utilities.exceptions import SIGTERMException
from tqdm.auto import tqdm

from vitac.algos.evaluation import run_episodes
from vitac.viz import policy_actor, record_episode, save_video


class EvaluationCallback(L.Callback):
    """Every `every` iterations, run the deterministic policy on `episodes` held-out seeded episodes; every
    `video_every` evaluations also record one episode (views and force fields) to `video_dir` and wandb.

    Args:
        make_envs: builds the evaluation vector env (called once, lazily).
        every: iterations between evaluations.
        episodes: episodes per evaluation.
        seed: first evaluation seed (held out from the training seeds).
        make_video_env: builds the single env videos are recorded in (None: no videos).
        video_every: evaluations between videos (0: none).
        video_dir: where the videos are written.
    """

    def __init__(self, make_envs, every: int, episodes: int, seed: int = 1_000_000, make_video_env=None,
                 video_every: int = 0, video_dir=None):
        self.make_envs, self.every, self.episodes, self.seed = make_envs, every, episodes, seed
        self.make_video_env, self.video_every, self.video_dir = make_video_env, video_every, video_dir
        self.envs = None
        self.evaluations = 0

    def on_train_epoch_end(self, trainer, module):
        iteration = trainer.current_epoch + 1
        if iteration % self.every and iteration != trainer.max_epochs:
            return
        if self.envs is None:
            self.envs = self.make_envs()
        summary = run_episodes(module.policy, self.envs, self.episodes, self.seed)
        metrics = {"eval/success_rate": summary["success_rate"]}
        if summary["steps_to_success_mean"] is not None:
            metrics["eval/steps_to_success"] = summary["steps_to_success_mean"]
        module.log_dict(metrics, on_epoch=True)
        self.evaluations += 1
        if self.make_video_env is not None and self.video_every and self.evaluations % self.video_every == 0:
            self._record(trainer, module, iteration)

    def _record(self, trainer, module, iteration: int):
        env = self.make_video_env()
        try:
            module.policy.eval()
            frames, _ = record_episode(env, policy_actor(module.policy), self.seed, every=3)
        finally:
            env.close()
        path = save_video(frames, self.video_dir / f"iter_{iteration:05d}.mp4", every=3)
        for logger in trainer.loggers:
            if hasattr(logger, "log_video"):  # WandbLogger
                logger.log_video("eval/video", [str(path)], step=trainer.global_step)

    def teardown(self, trainer, module, stage):
        if self.envs is not None:
            self.envs.close()
            self.envs = None

    def on_exception(self, trainer, module, exception):
        # A run stopped by SIGTERM or an error skips teardown; unclosed renderers would be freed after EGL has
        # shut down at exit, each printing an EGL_NOT_INITIALIZED traceback.
        self.teardown(trainer, module, "fit")


class BestEvaluation(ModelCheckpoint):
    """best.ckpt by held-out success: considered only at the iterations that evaluate (the others do not
    report the metric, and ModelCheckpoint would warn at each of them)."""

    def _save_topk_checkpoint(self, trainer, monitor_candidates):
        if self.monitor in monitor_candidates:
            super()._save_topk_checkpoint(trainer, monitor_candidates)


def save_resume_point(trainer, path) -> None:
    """The full state as `path` (last.ckpt), with what only an exact resume needs (the algorithm's
    `resume_state`, e.g. DAgger's kept rollouts): periodic and best checkpoints stay small."""
    module = trainer.lightning_module
    module.saving_resume_point = True
    try:
        trainer.save_checkpoint(path, weights_only=False)
    finally:
        module.saving_resume_point = False


class LastCheckpoint(L.Callback):
    """`path` (last.ckpt) after every iteration, so that a SIGKILL or a crash loses at most the iteration in
    progress (about 14 MB written through a temporary file, ~1% of a privileged iteration). On SIGTERM (a SLURM
    preemption or time limit, `kill`) Lightning finishes the current iteration and stops with SIGTERMException;
    that state is saved too. A first Ctrl-C (SIGINT) is turned into that SIGTERM. Other exceptions can stop a run
    mid-rollout, whose state must not be saved."""

    def __init__(self, path):
        self.path = path
        self.signal_name = "SIGTERM"  # what stopped the run, for the message
        self._previous_sigint = None

    def on_train_start(self, trainer, module):
        # Ctrl-C (SIGINT) takes SIGTERM's path: the iteration finishes and is saved. A second Ctrl-C stops at once.
        if threading.current_thread() is threading.main_thread():
            self._previous_sigint = signal.signal(signal.SIGINT, self._interrupt)

    def _interrupt(self, signum, frame):
        self.signal_name = "SIGINT (Ctrl-C)"
        signal.signal(signal.SIGINT, signal.default_int_handler)
        print("\nvitac: Ctrl-C: finishing this iteration, then saving it (Ctrl-C again stops at once)", flush=True)
        os.kill(os.getpid(), signal.SIGTERM)

    def _restore(self):
        if self._previous_sigint is not None:
            signal.signal(signal.SIGINT, self._previous_sigint)
            self._previous_sigint = None

    def on_train_epoch_end(self, trainer, module):
        save_resume_point(trainer, self.path)

    def on_train_end(self, trainer, module):
        self._restore()

    def on_exception(self, trainer, module, exception):
        self._restore()
        if isinstance(exception, SIGTERMException):  # raised between iterations only
            save_resume_point(trainer, self.path)
            print(f"\nvitac: stopped by {self.signal_name} after {module.env_steps} env steps; saved to {self.path}",
                  flush=True)


class NonFiniteGuard(L.Callback):
    """Stop a run whose updates keep failing: an update skips a minibatch whose gradient is not finite (one bad
    minibatch must not poison every weight); `limit` iterations in a row that skipped any saves the state as
    `path` (last.ckpt: the weights those skips left untouched) and stops with an error naming the cause."""

    def __init__(self, path, limit: int):
        self.path, self.limit, self.streak = path, limit, 0

    def on_train_epoch_end(self, trainer, module):
        skipped = float(trainer.callback_metrics.get("losses/skipped_updates", 0.0))
        self.streak = self.streak + 1 if skipped > 0 else 0
        if self.streak >= self.limit:
            save_resume_point(trainer, self.path)
            raise RuntimeError(
                f"vitac: {self.streak} iterations in a row had non-finite gradients (trainer.max_nonfinite_iterations="
                f"{self.limit}); stopped after {module.env_steps} env steps and saved {self.path}. A learning rate too "
                "high for this policy, or non-finite observations (losses/skipped_updates, charts/broken_episodes "
                "in the metrics), are the usual causes")


class IterationProgressBar(L.Callback):
    """One bar over all iterations showing env steps/s, success rate and ETA. While DAgger's teacher still acts
    (beta > 0) the training episodes' success is shown as `success_with_teacher` beside the teacher's share of
    actions; `eval` is always the policy alone on held-out episodes."""

    def on_train_start(self, trainer, module):
        self.bar = tqdm(total=trainer.max_epochs, initial=trainer.current_epoch, desc=type(module).__name__, unit="it",
                        dynamic_ncols=True)

    def on_train_epoch_end(self, trainer, module):
        m = trainer.callback_metrics
        postfix = {"env_steps": int(module.env_steps), "SPS": f"{float(m.get('charts/SPS', 0)):.0f}"}
        success = f"{float(m.get('charts/success_rate', float('nan'))):.2f}"
        beta = float(m.get("charts/beta", 0.0))
        if beta > 0:  # DAgger's hand-over: the training episodes' success is partly the teacher's
            postfix.update(teacher_acts=f"{beta:.0%}", success_with_teacher=success)
        else:
            postfix["success"] = success
        if "eval/success_rate" in m:  # held-out episodes, the policy alone
            postfix["eval"] = f"{float(m['eval/success_rate']):.2f}"
        self.bar.set_postfix(postfix)
        self.bar.update(1)

    def on_train_end(self, trainer, module):
        self.bar.close()

    def on_exception(self, trainer, module, exception):
        if hasattr(self, "bar"):  # an error before training started has no bar to close
            self.bar.close()


def run_callbacks(checkpoint: ModelCheckpoint, evaluation: EvaluationCallback, checkpoints: Path,
                  max_nonfinite_iterations: int) -> list[L.Callback]:
    """A training run's callbacks, in the order they run at an iteration's end: the periodic checkpoint, the
    best-evaluation checkpoint, the evaluation, the resume point, the progress bar and the non-finite guard."""
    return [checkpoint,
            # One best.ckpt however often the run resumed: a resumed attempt replaces it instead of adding best-v1.
            BestEvaluation(dirpath=checkpoints, filename="best", monitor="eval/success_rate", mode="max",
                           save_top_k=1, auto_insert_metric_name=False, enable_version_counter=False),
            evaluation, LastCheckpoint(checkpoints / "last.ckpt"), IterationProgressBar(),
            NonFiniteGuard(checkpoints / "last.ckpt", max_nonfinite_iterations)]
