"""Policy assembly: per-modality encoders -> fusion -> recurrent head, plus an optional asymmetric critic."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from vitac.models.normalizer import ForceFieldScale, RunningNormalizer
from vitac.models.symmetry import SymmetryRegularizer
from vitac.tasks.config import ObservationSpec


class VisuoTactilePolicy(nn.Module):
    """Gaussian recurrent actor-critic over a dict of observations.

    Args:
        obs_specs: the observations the actor reads, as the task declares them (images with their fusion
            role, vectors), in the task's order: images are fused in it, vector features follow in it.
        image_encoder: builds an encoder from an image shape (C, H, W); exposes `out_dim`.
        vector_encoder: builds an encoder from a vector size.
        fusion: builds the fusion module from (embed_dim, num_inputs); exposes `out_dim`, `requires`.
        head: builds the recurrent head from the feature size.
        regularizer: the symmetry prior (lambda_sym 0 turns it off).
        critic: builds the asymmetric critic from the critic-state size, or None to use the head's value.
        critic_state_dim: size of the critic state when `critic` is given.
        residual: builds a `vitac.models.residual.ResidualHead` from the head's LSTM width, or None. With one, the
            rest of the actor (encoders, fusion, head and their input statistics) is a frozen student: only the
            residual head (and the critic) learn, and the student's weights load by their own names.
    """

    def __init__(self, obs_specs: dict[str, ObservationSpec], image_encoder: Callable, vector_encoder: Callable,
                 fusion: Callable, head: Callable, regularizer: SymmetryRegularizer, critic: Callable | None = None,
                 critic_state_dim: int | None = None, residual: Callable | None = None):
        super().__init__()
        critic_only = sorted(k for k, spec in obs_specs.items() if spec.critic_only)
        if critic_only:
            raise ValueError(f"obs.modalities={list(obs_specs)} is not allowed: {critic_only} are the critic's "
                             "observations, not the actor's")
        self.image_keys = [k for k, spec in obs_specs.items() if spec.kind == "image"]
        self.vector_keys = [k for k, spec in obs_specs.items() if spec.kind == "vector"]
        self.roles = {k: obs_specs[k].role for k in self.image_keys}
        shapes = {k: tuple(spec.shape) for k, spec in obs_specs.items()}
        self.encoders = nn.ModuleDict({k: image_encoder(in_shape=shapes[k]) for k in self.image_keys})
        self.vector_encoders = nn.ModuleDict({k: vector_encoder(in_dim=int(shapes[k][0])) for k in self.vector_keys})
        self.normalizers = nn.ModuleDict({k: RunningNormalizer(shapes[k]) for k in self.vector_keys})
        # The tactile pads' force fields, on one learned scale (camera pixels are scaled to [0, 1] by the encoder).
        self.force_field_keys = [k for k in self.image_keys if self.roles[k] in ("left", "right")]
        self.force_scale = ForceFieldScale(shapes[self.force_field_keys[0]][0]) if self.force_field_keys else None
        features = 0
        self.fusion = None
        if self.image_keys:
            embed = {self.encoders[k].out_dim for k in self.image_keys}
            if len(embed) != 1:
                raise ValueError(f"image encoders disagree on embedding size: {embed}")
            self.fusion = fusion(embed_dim=embed.pop(), num_inputs=len(self.image_keys))
            features += self.fusion.out_dim
        features += sum(self.vector_encoders[k].out_dim for k in self.vector_keys)
        self.head = head(in_dim=features)
        self.regularizer = regularizer
        self.uses_symmetry = regularizer.active and {"left", "right"} <= set(self.roles.values())
        self._pad_keys = tuple(next((k for k, role in self.roles.items() if role == side), None)
                               for side in ("left", "right"))
        self.critic = None
        if critic is not None:
            self.critic = critic(in_dim=critic_state_dim, memory_dim=self.head.hidden)
            self.critic_normalizer = RunningNormalizer((critic_state_dim,))
        self.feature_dim = features
        self.residual = None
        if residual is not None:
            for name, parameter in self.named_parameters():
                if not name.startswith("critic"):
                    parameter.requires_grad_(False)
            self.residual = residual(in_dim=self.head.hidden, action_dim=self.head.mean.out_features)

    @property
    def input_keys(self) -> list[str]:
        """Every observation `forward` reads: the actor's images and vectors, and the critic state with a critic."""
        return self.image_keys + self.vector_keys + (["critic_state"] if self.critic is not None else [])

    @property
    def device(self) -> torch.device:
        return next(self.parameters()).device

    def step_inputs(self, obs: dict, starts: torch.Tensor) -> tuple[dict, torch.Tensor]:
        """One time step of observations (B, ...) (numpy or CPU tensors) and start flags (B,) as (1, B, ...)
        inputs on this policy's device."""
        device = self.device
        return {k: torch.as_tensor(v)[None].to(device) for k, v in obs.items()}, starts[None].to(device)

    def initial_state(self, batch: int, device=None):
        return self.head.initial_state(batch, device)

    @torch.no_grad()
    def update_normalizers(self, obs: dict, actor: bool = True) -> None:
        """Update the input statistics from a batch of observations: the actor's unless `actor` is false (it then
        acts exactly as before), and the critic's."""
        actor = actor and self.residual is None  # a residual policy's student keeps its statistics
        actor_keys = self.vector_keys + self.force_field_keys if actor else []
        keys = actor_keys + (["critic_state"] if self.critic is not None else [])
        for k in keys:  # one NaN would silently poison the statistics, and every output after them
            if not torch.isfinite(obs[k]).all():
                raise FloatingPointError(f"observation {k!r} holds non-finite values; refusing to update its normalizer")
        for k in self.vector_keys if actor else []:
            self.normalizers[k].update(obs[k])
        if actor and self.force_scale is not None:
            self.force_scale.update(torch.cat([obs[k] for k in self.force_field_keys]))
        if self.critic is not None:
            self.critic_normalizer.update(obs["critic_state"])

    def _flat_image(self, obs: dict, key: str, lead: tuple) -> torch.Tensor:
        """Image `key` with its leading (T, B) dims flattened, force fields on their learned scale."""
        image = obs[key].reshape(-1, *obs[key].shape[len(lead):])
        return self.force_scale(image.float()) if key in self.force_field_keys else image

    def _features(self, obs: dict, lead: tuple):
        """Encode (T*B)-flattened observations; returns features (T, B, F) and the image embeddings."""
        flat = lambda x: x.reshape(-1, *x.shape[len(lead):])  # noqa: E731
        embeddings = {self.roles[k]: self.encoders[k](self._flat_image(obs, k, lead)) for k in self.image_keys}
        parts = [self.fusion(embeddings)] if self.fusion is not None else []
        for k in self.vector_keys:
            parts.append(self.vector_encoders[k](self.normalizers[k](flat(obs[k]).float())))
        return torch.cat(parts, dim=-1).reshape(*lead, -1), embeddings

    def forward(self, obs: dict, state, episode_starts: torch.Tensor, with_aux: bool = False):
        """obs values (T, B, ...), episode_starts (T, B).

        Returns mean, log_std (T, B, A), value (T, B), next state and, with `with_aux`, the symmetry
        loss per sample (T*B,) or None.
        """
        lead = tuple(episode_starts.shape)
        features, embeddings = self._features(obs, lead)
        memory = self.residual is not None or (self.critic is not None and self.critic.reads_actor_memory)
        mean, log_std, value, state, *lstm_out = self.head(features, state, episode_starts, with_memory=memory)
        if self.residual is not None:
            mean, log_std = self.residual(lstm_out[0], mean)
        if self.critic is not None:
            critic_state = obs["critic_state"].reshape(-1, obs["critic_state"].shape[-1]).float()
            own = lstm_out[0].reshape(-1, lstm_out[0].shape[-1]) if self.critic.reads_actor_memory else None
            value = self.critic(self.critic_normalizer(critic_state), own).reshape(lead)
        if not with_aux:
            return mean, log_std, value, state
        sym = self._symmetry_loss(obs, lead, embeddings) if self.uses_symmetry else None
        return mean, log_std, value, state, sym

    def _symmetry_loss(self, obs: dict, lead: tuple, embeddings: dict) -> torch.Tensor:
        """The prior's loss per sample, read where `regularizer.placement` says."""
        left, right = self._pad_keys
        if self.regularizer.placement == "self_attention":
            return self.regularizer.per_sample_attended(
                self.fusion, (self.encoders[left], self.encoders[right]),
                (self._flat_image(obs, left, lead), self._flat_image(obs, right, lead)),
                (embeddings["left"], embeddings["right"]))
        return self.regularizer.per_sample(embeddings["left"], self.encoders[right], self._flat_image(obs, right, lead))
