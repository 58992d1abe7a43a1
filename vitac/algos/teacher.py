"""A frozen teacher run along the student's trajectory: the labels of online distillation (DAgger) and of the
imitation term of PPO fine-tuning (KickstartPPO).

The teacher reads its own observations through its own frozen normalizers and carries its own recurrent state,
which advances along the trajectory actually taken and resets where episodes restart.
"""

from __future__ import annotations

import torch

from vitac.models.policy import VisuoTactilePolicy


class TeacherLabels:
    """The teacher's mean action, within the action bounds, at every step the environments take.

    Args:
        teacher: a trained policy (frozen here, never in training mode).
        observed: the observation names the environments provide; the teacher's must be among them.
    """

    def __init__(self, teacher: VisuoTactilePolicy, observed):
        missing = [k for k in teacher.input_keys if k not in observed]
        if missing:
            raise ValueError(f"teacher_ckpt: the teacher reads {missing}, which the environments do not observe")
        self.teacher = teacher.requires_grad_(False).eval()
        self.state = None

    def start(self, num_envs: int, device) -> None:
        """Move the teacher to `device`; a fresh run starts its recurrent state (a resumed one restored it)."""
        self.teacher.to(device)
        if self.state is None:
            self.state = self.teacher.initial_state(num_envs, device)

    @torch.no_grad()
    def __call__(self, obs: dict, starts: torch.Tensor) -> torch.Tensor:
        """The label (N, A), on the CPU, of the step whose observation is `obs` (episode-start flags `starts`),
        taken before the environments step. Clamped to the bounds: beyond them every value executes the same,
        and matching it there would only spend the student's capacity."""
        inputs, starts = self.teacher.step_inputs({k: obs[k] for k in self.teacher.input_keys}, starts)
        label, _, _, self.state = self.teacher(inputs, self.state, starts)
        return label[0].cpu().clamp(-1.0, 1.0)

    def state_dict(self) -> dict:
        return dict(teacher_state=tuple(s.cpu() for s in self.state))

    def load_state_dict(self, state: dict, device) -> None:
        self.state = tuple(s.to(device) for s in state["teacher_state"])
