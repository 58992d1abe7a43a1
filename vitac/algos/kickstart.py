"""PPO with an imitation term to a teacher whose weight anneals to zero (Kickstarting, Schmitt et al. 2018; TGRL):
a distilled student keeps its teacher's actions while its critic and its first updates find their feet, then
PPO alone decides, so the student may pass the teacher instead of copying its failures.

    python -m vitac.train experiment=table1/<row> finetune=kickstart init_ckpt=<student run>/checkpoints/last.ckpt
"""

from __future__ import annotations

import torch

from vitac.algos.ppo import PPO
from vitac.algos.teacher import TeacherLabels
from vitac.models.policy import VisuoTactilePolicy
from vitac.utils.checks import check_int, is_number, refuse


def check_kickstart(imitation_coef, imitation_iterations) -> None:
    """Refuse an out-of-range value of the imitation term, with its key."""
    if not is_number(imitation_coef) or imitation_coef < 0:
        refuse("algo.imitation_coef", imitation_coef, "a number >= 0")
    check_int("algo.imitation_iterations", imitation_iterations, 0)


class KickstartPPO(PPO):
    """PPO whose loss adds `imitation_weight` times the squared distance between the student's mean action and
    the teacher's (within the action bounds, as DAgger's labels) on the states of the rollout.

    The weight is `imitation_coef` at the first iteration after the critic's warm-up (`critic_warmup_iterations`,
    PPO's) and falls linearly to 0 over `imitation_iterations` iterations; from then on the update is PPO's own.
    The teacher runs along the trajectory with its own observations, normalizers and recurrent state
    (`vitac.algos.teacher`); its state travels in checkpoints, so a resume continues the schedule exactly.

    Args:
        policy, envs: PPO's.
        teacher: the trained policy whose mean actions the imitation term pulls towards (frozen).
        imitation_coef: the term's weight at its start.
        imitation_iterations: iterations over which the weight falls to 0 (0: no imitation term).
        **ppo: every other argument of `vitac.algos.ppo.PPO`.
    """

    needs_teacher = True  # train() loads `teacher_ckpt` and adds the teacher's observations to the environments'
    minibatch_fields = PPO.minibatch_fields + ("labels",)
    logged_losses = PPO.logged_losses + ("imitation_loss",)

    def __init__(self, policy: VisuoTactilePolicy, envs, teacher: VisuoTactilePolicy, imitation_coef: float = 1.0,
                 imitation_iterations: int = 50, **ppo):
        super().__init__(policy, envs, **ppo)
        check_kickstart(imitation_coef, imitation_iterations)
        self.hp.update(imitation_coef=imitation_coef, imitation_iterations=imitation_iterations)
        # Not a submodule: the teacher stays out of the student's checkpoints, optimizer and train/eval switches.
        self.labels = TeacherLabels(teacher, envs.single_observation_space.spaces)

    @property
    def imitation_weight(self) -> float:
        """The imitation term's weight this iteration, 0 in the critic's warm-up (a function of the iteration: a
        resumed run continues it)."""
        hp = self.hp
        if not hp["imitation_iterations"] or self.actor_frozen:
            return 0.0
        since = max(0, self.current_epoch - hp["critic_warmup_iterations"])
        return hp["imitation_coef"] * max(0.0, 1.0 - since / hp["imitation_iterations"])

    # ----------------------------------------------------------------------------------- rollout
    def on_train_start(self):
        super().on_train_start()
        self.labels.start(self.envs.num_envs, self.device)

    def extra_state(self) -> dict:
        return self.labels.state_dict()

    def load_extra_state(self, state: dict) -> None:
        self.labels.load_state_dict(state, self.device)

    def act(self, t, obs, mean, log_std, value):
        buf = self.buffer
        if getattr(buf, "labels", None) is None:
            buf.labels = torch.zeros_like(buf.actions)
        buf.labels[t] = self.labels(obs, self._starts)  # the teacher's mean on the observation at t
        return super().act(t, obs, mean, log_std, value)

    # ------------------------------------------------------------------------------------ update
    def minibatch_losses(self, mb: dict) -> dict:
        terms = super().minibatch_losses(mb)
        imitation = (terms["mean"] - mb["labels"]).square().sum(-1).mean()
        weight = self.imitation_weight
        if weight:
            terms["loss"] = terms["loss"] + weight * imitation
        return dict(terms, imitation_loss=imitation)

    def update(self) -> dict:
        return dict(super().update(), **{"charts/imitation_weight": self.imitation_weight})
