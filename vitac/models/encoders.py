"""Per-modality encoders: conv + spatial soft-argmax for images (paper's architecture table), MLP for vectors."""

from __future__ import annotations

import functools

import torch
from torch import nn

from vitac.utils.checks import check_flag, check_widths
from vitac.utils.records import describe_cpu


@functools.cache
def native_bfloat16(device_type: str) -> bool:
    """Whether `device_type` computes in bfloat16 natively: a CUDA GPU that supports it, or a CPU with
    AVX512-BF16 or AMX. Elsewhere bfloat16 convolutions are emulated, ten times slower than float32 on one
    AVX2-only CPU (README)."""
    if device_type == "cuda":
        return torch.cuda.is_bf16_supported()
    return device_type == "cpu" and bool(describe_cpu()["bfloat16"])


class SpatialSoftArgmax(nn.Module):
    """Expected (x, y) image coordinates in [-1, 1] of each channel's softmax: (B, C, H, W) -> (B, 2C).

    Args:
        height, width: feature map size (the coordinate grids are built once).
    """

    def __init__(self, height: int, width: int):
        super().__init__()
        grid_y, grid_x = torch.meshgrid(torch.linspace(-1.0, 1.0, height), torch.linspace(-1.0, 1.0, width),
                                        indexing="ij")
        self.register_buffer("grid", torch.stack([grid_x.reshape(-1), grid_y.reshape(-1)], dim=1), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, h, w = x.shape
        weights = torch.softmax(x.reshape(b, c, h * w), dim=-1)
        expected = weights @ self.grid.to(x.dtype)  # (B, C, 2): expected x and y per channel
        return torch.cat([expected[..., 0], expected[..., 1]], dim=-1)


class ConvSoftArgmaxEncoder(nn.Module):
    """Conv 8x8/2 (32) -> Conv 4x4/1 (64) -> Conv 3x3/1 (64) -> spatial soft-argmax, ReLU, no padding.

    uint8 images (camera pixels) are scaled to [0, 1]; float images (force fields) are used as they are.

    Args:
        in_shape: (C, H, W) of the input image.
        channels, kernels, strides: the three conv layers.
        bf16: run the convolutions under bfloat16 autocast (TacSL trains with mixed precision): true, false, or
            "auto" for wherever the device computes bfloat16 natively (`native_bfloat16`). The convs are most of
            an image policy's arithmetic; on CPUs with AVX512-BF16 (or AMX) they run about twice as fast.
            Weights, gradients and the soft-argmax stay float32.
    """

    def __init__(self, in_shape, channels=(32, 64, 64), kernels=(8, 4, 3), strides=(2, 1, 1),
                 bf16: bool | str = False):
        super().__init__()
        for name, value in (("channels", channels), ("kernels", kernels), ("strides", strides)):
            check_widths(f"encoder.image.{name}", value, len(channels) if name != "channels" else None)
        check_flag("encoder.image.bf16", bf16, auto=True)
        layers, c = [], in_shape[0]
        h, w = in_shape[1], in_shape[2]
        for out, k, s in zip(channels, kernels, strides, strict=True):
            layers += [nn.Conv2d(c, out, k, s), nn.ReLU()]
            c, h, w = out, (h - k) // s + 1, (w - k) // s + 1
            if h < 1 or w < 1:
                raise ValueError(f"encoder.image.kernels={list(kernels)} is not allowed with an observation of shape "
                                 f"{tuple(in_shape)}: it is too small for conv kernel {k} stride {s}, which needs at "
                                 f"least {k}x{k} pixels at that layer (tactile maps are task.taxel_rows x "
                                 f"task.taxel_cols, camera images task.camera_size square)")
        # channels-last: oneDNN's convolutions skip layout reorders (measured ~5% at batch 1, ~20% in training).
        self.conv = nn.Sequential(*layers[:-1]).to(memory_format=torch.channels_last)  # soft-argmax follows conv3
        self.softargmax = SpatialSoftArgmax(h, w)
        self.in_shape = tuple(in_shape)
        self.out_dim = 2 * channels[-1]
        self.bf16 = bf16

    def uses_bf16(self, device_type: str) -> bool:
        """Whether the convolutions run in bfloat16 on `device_type` ("cpu", "cuda")."""
        return native_bfloat16(device_type) if self.bf16 == "auto" else self.bf16

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if tuple(x.shape[1:]) != self.in_shape:
            raise ValueError(f"image of shape {tuple(x.shape[1:])} does not fit an encoder built for {self.in_shape}")
        x = x.float() / 255.0 if x.dtype == torch.uint8 else x.float()  # camera pixels arrive as uint8
        with torch.autocast(x.device.type, dtype=torch.bfloat16, enabled=self.uses_bf16(x.device.type)):
            features = self.conv(x.contiguous(memory_format=torch.channels_last))
        return self.softargmax(features.float())


class VectorEncoder(nn.Module):
    """Identity (TacSL's `{}` preprocessor) or a small ELU MLP for vector observations."""

    def __init__(self, in_dim: int, hidden: tuple = ()):
        super().__init__()
        check_widths("encoder.vector.hidden", hidden)
        layers, d = [], in_dim
        for h in hidden:
            layers += [nn.Linear(d, h), nn.ELU()]
            d = h
        self.net = nn.Sequential(*layers)
        self.out_dim = d

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x.float())
