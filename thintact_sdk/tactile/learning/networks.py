"""The CycleGAN networks of Real2Sim (paper §VI-C, after Zhu et al. 2017).

A small ResNet generator (two stride-2 downsamplings, residual blocks at a quarter of the
resolution, two upsamplings) and a PatchGAN discriminator. Both are fully convolutional, so
one network serves any image size whose sides are multiples of 4 (:func:`pad_to_multiple`
handles the others).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F  # noqa: N812


def _conv_norm_relu(c_in: int, c_out: int, k: int, stride: int = 1) -> list[nn.Module]:
    pad = k // 2
    return [
        nn.Conv2d(c_in, c_out, k, stride, pad, padding_mode="reflect"),
        nn.InstanceNorm2d(c_out),
        nn.ReLU(),
    ]


class ResidualBlock(nn.Module):
    """Two 3×3 convolutions with instance norm and an identity shortcut."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.body = nn.Sequential(
            *_conv_norm_relu(channels, channels, 3),
            nn.Conv2d(channels, channels, 3, 1, 1, padding_mode="reflect"),
            nn.InstanceNorm2d(channels),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


class ResnetGenerator(nn.Module):
    """Image-to-image generator: ``B × 3 × H × W`` in [-1, 1] → the same shape in [-1, 1].

    Parameters
    ----------
    width
        Channels of the full-resolution layers (×2 and ×4 after each downsampling).
    blocks
        Residual blocks at quarter resolution.
    edge_kernel
        Kernel of the first and last (full-resolution) convolutions; Zhu et al. use 7, a
        5 keeps inference within a few ms on a CPU at tactile working resolutions.
    """

    def __init__(self, width: int = 8, blocks: int = 3, channels: int = 3,
                 edge_kernel: int = 5) -> None:
        super().__init__()
        w, k = width, edge_kernel
        layers: list[nn.Module] = [*_conv_norm_relu(channels, w, k)]
        layers += _conv_norm_relu(w, 2 * w, 3, 2) + _conv_norm_relu(2 * w, 4 * w, 3, 2)
        layers += [ResidualBlock(4 * w) for _ in range(blocks)]
        for c_in, c_out in ((4 * w, 2 * w), (2 * w, w)):
            layers += [nn.Upsample(scale_factor=2, mode="nearest"), *_conv_norm_relu(c_in, c_out, 3)]
        layers += [nn.Conv2d(w, channels, k, 1, k // 2, padding_mode="reflect"), nn.Tanh()]
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class PatchDiscriminator(nn.Module):
    """PatchGAN: a map of real/fake scores, one per overlapping patch (LSGAN targets 1/0)."""

    def __init__(self, width: int = 32, layers: int = 3, channels: int = 3) -> None:
        super().__init__()
        mods: list[nn.Module] = [nn.Conv2d(channels, width, 4, 2, 1), nn.LeakyReLU(0.2)]
        c = width
        for i in range(1, layers):
            stride = 2 if i < layers - 1 else 1
            mods += [nn.Conv2d(c, 2 * c, 4, stride, 1), nn.InstanceNorm2d(2 * c),
                     nn.LeakyReLU(0.2)]
            c *= 2
        mods.append(nn.Conv2d(c, 1, 4, 1, 1))
        self.net = nn.Sequential(*mods)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


def pad_to_multiple(x: torch.Tensor, multiple: int = 4) -> tuple[torch.Tensor, tuple[int, int]]:
    """Reflect-pad ``B × C × H × W`` so H and W are multiples of ``multiple``.

    Returns the padded tensor and the original ``(H, W)`` to crop back to.
    """
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph or pw:
        x = F.pad(x, (0, pw, 0, ph), mode="reflect")
    return x, (h, w)
