"""Online distillation (DAgger) on the shared rollout loop: the student acts, a teacher labels every state it
visits with its mean action, and the student learns to match those labels.

The teacher is any trained policy of the project (`teacher_ckpt=`, by default the shipped 97% one),
run with its own observations, its own frozen normalizer statistics and its own recurrent state, which
advances along the trajectory actually taken and resets where episodes restart. The student trains by
truncated back-propagation over the stored sequences with the stored recurrent state, as PPO does. The
dataset is the current rollout only (rsl_rl's choice): memory stays one rollout, and the labels of states
the student reaches late in training are the ones it learns from. `dataset_rollouts` > 1 keeps the last few
rollouts instead, as DAgger proper aggregates its dataset, at the same number of gradient steps.
"""

from __future__ import annotations

import torch
from lightning.pytorch.utilities import move_data_to_device

from vitac.algos import losses
from vitac.algos.buffer import SequenceStore, check_batch_layout
from vitac.algos.curriculum import RandomizationCurriculum
from vitac.algos.rollout import RolloutAlgorithm
from vitac.algos.teacher import TeacherLabels
from vitac.models.policy import VisuoTactilePolicy
from vitac.utils.checks import check_int, is_number, refuse

LOSSES = ("mse", "nll")
STUDENT_ACTIONS = ("mean", "sample")
LR_SCHEDULES = ("fixed", "linear")


class DAgger(RolloutAlgorithm):
    """The student's actions (or, with probability beta, the teacher's) drive the environments; the loss is the
    distance to the teacher's mean action within the action bounds, plus the symmetry prior's term (`lambda_sym *
    L_sym`, or relative to the distance) when the student's regularizer is on.

    Args:
        policy: the student.
        envs: the vector env; its observations include the teacher's as well as the student's.
        teacher: the trained policy whose mean actions are the labels (frozen, never in training mode).
        horizon, seq_len, minibatch_size, mini_epochs: rollout length, BPTT length and minibatching, as PPO's.
        lr, grad_norm: Adam's learning rate and the gradient-norm clip.
        lr_schedule: "fixed" (lr throughout) or "linear": from lr at the first iteration towards 0 at the run's
            last (`trainer.iterations`), so that the last checkpoints settle instead of swinging.
        loss: "mse" on the mean action, or "nll" (the teacher's mean under the student's Gaussian: the student's
            action noise is learned too).
        beta_start, beta_end, beta_iterations: the probability of executing the teacher's action instead of the
            student's, per environment and step, moved linearly from beta_start to beta_end over beta_iterations
            iterations (beta_start = beta_end = 0: the student always acts).
        student_actions: "mean" (the deterministic student, as it is evaluated) or "sample" (with its noise).
        dataset_rollouts: how many of the latest rollouts each update draws its sequences from (1: the current
            one only). Every update takes mini_epochs rollouts' worth of sequences, so its cost stays the same;
            the kept rollouts travel in last.ckpt (exact resume), about 38 MB each for a camera + tactile student.
        seed, rollout_threads, update_threads, run_config, curriculum: the rollout loop's.
    """

    needs_teacher = True  # train() loads `teacher_ckpt` and adds the teacher's observations to the environments'

    def __init__(self, policy: VisuoTactilePolicy, envs, teacher: VisuoTactilePolicy, horizon: int = 64,
                 seq_len: int = 32, minibatch_size: int = 256, mini_epochs: int = 4, lr: float = 3e-4,
                 lr_schedule: str = "fixed", grad_norm: float = 1.0, loss: str = "mse", beta_start: float = 1.0,
                 beta_end: float = 0.0, beta_iterations: int = 20, student_actions: str = "mean",
                 dataset_rollouts: int = 1, seed: int = 0, rollout_threads: int = 1, update_threads: int = 2,
                 run_config: dict | None = None, curriculum: RandomizationCurriculum | None = None):
        super().__init__(policy, envs, horizon, seq_len, seed, rollout_threads, update_threads, run_config, curriculum)
        self.hp = dict(minibatch_size=minibatch_size, mini_epochs=mini_epochs, lr=lr, lr_schedule=lr_schedule,
                       grad_norm=grad_norm, loss=loss, beta_start=beta_start, beta_end=beta_end,
                       beta_iterations=beta_iterations, student_actions=student_actions,
                       dataset_rollouts=dataset_rollouts)
        check_dagger(self.hp, horizon, envs.num_envs, seq_len)
        # Not a submodule: the teacher stays out of the student's checkpoints, optimizer and train/eval switches.
        self.labels = TeacherLabels(teacher, envs.single_observation_space.spaces)
        self.dataset = SequenceStore(dataset_rollouts)

    def configure_optimizers(self):
        return torch.optim.Adam([p for p in self.policy.parameters() if p.requires_grad], lr=self.hp["lr"])

    @property
    def learning_rate(self) -> float:
        """Adam's rate for this iteration's update (a function of the iteration: a resumed run continues it)."""
        if self.hp["lr_schedule"] == "fixed":
            return self.hp["lr"]
        return self.hp["lr"] * (1.0 - self.current_epoch / self.trainer.max_epochs)

    @property
    def beta(self) -> float:
        hp = self.hp
        progress = min(1.0, self.current_epoch / hp["beta_iterations"]) if hp["beta_iterations"] else 1.0
        return hp["beta_start"] + (hp["beta_end"] - hp["beta_start"]) * progress

    # ----------------------------------------------------------------------------------- rollout
    def on_train_start(self):
        super().on_train_start()
        self.labels.start(self.envs.num_envs, self.device)

    def extra_state(self) -> dict:
        return self.labels.state_dict()

    def resume_state(self) -> dict:
        # One rollout kept is this iteration's, which the next one replaces: nothing to carry.
        return dict(dataset=self.dataset.state_dict()) if self.dataset.capacity > 1 else {}

    def load_extra_state(self, state: dict) -> None:
        self.labels.load_state_dict(state, self.device)
        saved = state.get("dataset")
        if saved is not None and self.dataset.capacity == saved["capacity"]:  # else (a changed dataset_rollouts)
            self.dataset.load_state_dict(saved)                                # the dataset starts afresh

    def act(self, t, obs, mean, log_std, value):
        buf = self.buffer
        if getattr(buf, "labels", None) is None:
            buf.labels = torch.zeros_like(buf.actions)
        label = self.labels(obs, self._starts)  # the teacher's mean on the observation at t
        buf.labels[t] = label
        student = mean
        if self.hp["student_actions"] == "sample":
            student = mean + log_std.exp() * torch.randn(mean.shape, generator=self.generator)
        beta = self.beta
        if beta <= 0.0:
            return student
        if beta >= 1.0:
            return label.clone()
        teacher_acts = torch.rand(mean.shape[0], generator=self.generator) < beta
        return torch.where(teacher_acts[:, None], label, student)

    # ------------------------------------------------------------------------------------ update
    def minibatch_losses(self, mb: dict) -> dict:
        """The distillation loss of one minibatch of sequences, its action MSE and the symmetry term."""
        policy = self.policy
        mean, log_std, _, _, sym = policy(mb["obs"], mb["state"], mb["starts"], with_aux=True)
        mse = (mean - mb["labels"]).square().mean()
        distill = mse if self.hp["loss"] == "mse" else -losses.gaussian_log_prob(mb["labels"], mean, log_std).mean()
        sym_loss = sym.mean() if sym is not None else torch.zeros((), device=mean.device)
        return dict(loss=distill + policy.regularizer.term(sym_loss, distill), distill_loss=distill, action_mse=mse,
                    sym_loss=sym_loss)

    def update(self) -> dict:
        hp, policy = self.hp, self.policy
        optimizer = self.optimizers()
        for group in optimizer.param_groups:
            group["lr"] = self.learning_rate
        sums: dict[str, float] = {}
        count = 0
        self.dataset.add(self.buffer)
        rollout_steps = self.horizon * self.envs.num_envs
        for _ in range(hp["mini_epochs"]):
            for mb in self.dataset.minibatches(hp["minibatch_size"], self.generator, rollout_steps):
                terms = self.minibatch_losses(move_data_to_device(mb, self.device))
                optimizer.zero_grad()
                self.manual_backward(terms["loss"])
                grad_norm = torch.nn.utils.clip_grad_norm_(policy.parameters(), hp["grad_norm"])
                if not torch.isfinite(grad_norm):  # one bad minibatch must not poison every weight
                    sums["skipped_updates"] = sums.get("skipped_updates", 0.0) + 1.0
                    continue
                optimizer.step()
                count += 1
                for k, v in dict(terms, grad_norm=grad_norm).items():
                    sums[k] = sums.get(k, 0.0) + float(v.detach())
        policy.update_normalizers({k: v.reshape(-1, *v.shape[2:]) for k, v in self.buffer.obs.items()})
        skipped = sums.pop("skipped_updates", 0.0)
        metrics = {f"losses/{k}": v / max(count, 1) for k, v in sums.items()}
        metrics.update({"losses/skipped_updates": skipped, "charts/beta": self.beta,
                        "charts/lr": optimizer.param_groups[0]["lr"]})
        return metrics


def check_dagger(hp: dict, horizon: int, num_envs: int, seq_len: int) -> None:
    """Refuse an out-of-range value of conf/algo/dagger.yaml, with its key."""
    for name in ("mini_epochs", "beta_iterations", "dataset_rollouts"):
        check_int(f"algo.{name}", hp[name], 0 if name == "beta_iterations" else 1)
    for name in ("lr", "grad_norm"):
        if not is_number(hp[name]) or not hp[name] > 0:
            refuse(f"algo.{name}", hp[name], "a number > 0")
    for name in ("beta_start", "beta_end"):
        if not is_number(hp[name]) or not 0 <= hp[name] <= 1:
            refuse(f"algo.{name}", hp[name], "a number in [0, 1]")
    if hp["loss"] not in LOSSES:
        refuse("algo.loss", hp["loss"], f"one of {list(LOSSES)}")
    if hp["lr_schedule"] not in LR_SCHEDULES:
        refuse("algo.lr_schedule", hp["lr_schedule"], f"one of {list(LR_SCHEDULES)}")
    if hp["student_actions"] not in STUDENT_ACTIONS:
        refuse("algo.student_actions", hp["student_actions"], f"one of {list(STUDENT_ACTIONS)}")
    check_batch_layout(horizon, num_envs, seq_len, hp["minibatch_size"])
