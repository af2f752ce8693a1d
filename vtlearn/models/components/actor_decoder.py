"""ACTOR upsampling decoder (thesis ch.8, Sec. 8.2.2, Fig. 8.2(a)).

A fully connected layer with output size 1024, then five transposed (de-)convolutions that upsample
the global feature vector into the dense cloud of 2048 x 3 points. The kernel sizes of Fig. 8.2(a)
are not in the thesis text; here each transposed convolution has kernel = stride, so the point count
grows 1 -> 4 -> 16 -> 64 -> 256 -> 2048 (a tree: every point is emitted by one parent feature).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

__all__ = ["ActorDecoder", "StridedConvTranspose1d"]


class StridedConvTranspose1d(nn.ConvTranspose1d):
    """``nn.ConvTranspose1d`` with kernel = stride (no overlap), computed as one matrix product.

    Without overlap every input position emits ``kernel_size`` outputs independently, so the layer is
    a per-position linear map; this avoids PyTorch's slow CPU path for transposed convolutions.
    Same parameters and result as the parent class (tested).

    Shapes:
        x: (B, C_in, L) -> (B, C_out, L * stride)
    """

    def __init__(self, in_channels: int, out_channels: int, stride: int, bias: bool = True) -> None:
        super().__init__(in_channels, out_channels, kernel_size=stride, stride=stride, bias=bias)

    def forward(self, x: Tensor) -> Tensor:  # type: ignore[override]
        b, c_in, length = x.shape
        k = self.kernel_size[0]
        w = self.weight.reshape(c_in, -1)  # C_in x (C_out * k)
        y = (x.transpose(1, 2) @ w).reshape(b, length, self.out_channels, k)  # B x L x C_out x k
        y = y.permute(0, 2, 1, 3).reshape(b, self.out_channels, length * k)
        if self.bias is not None:
            y = y + self.bias[None, :, None]
        return y


class ActorDecoder(nn.Module):
    """Global feature vector -> dense cloud.

    Args:
        in_channels: size of the global feature vector (1024).
        fc_channels: output of the fully connected layer (thesis: 1024).
        deconv_channels: output channels of the first four transposed convolutions (the fifth gives xyz).
        strides: kernel size = stride of the five transposed convolutions; their product is the
            number of output points (default 4*4*4*4*8 = 2048).

    Shapes:
        z: (B, in_channels); returns (B, prod(strides), 3).
    """

    def __init__(
        self,
        in_channels: int = 1024,
        fc_channels: int = 1024,
        deconv_channels: tuple[int, ...] = (512, 256, 256, 128),
        strides: tuple[int, ...] = (4, 4, 4, 4, 8),
    ) -> None:
        super().__init__()
        if len(strides) != len(deconv_channels) + 1:
            raise ValueError(
                f"strides: need one more entry than deconv_channels, "
                f"got {len(strides)} and {len(deconv_channels)}"
            )
        if any(s < 1 for s in strides):
            raise ValueError(f"strides: must be positive, got {strides}")
        self.in_channels = int(in_channels)
        self.num_points = math.prod(strides)
        self.fc = nn.Linear(in_channels, fc_channels, bias=False)
        self.fc_norm = nn.BatchNorm1d(fc_channels)
        layers: list[nn.Module] = []
        c_in = fc_channels
        for i, s in enumerate(strides):
            c_out = deconv_channels[i] if i < len(deconv_channels) else 3
            last = i == len(strides) - 1
            layers.append(StridedConvTranspose1d(c_in, c_out, s, bias=last))
            if not last:
                layers.append(nn.BatchNorm1d(c_out))
                layers.append(nn.ReLU())
            c_in = c_out
        self.deconvs = nn.Sequential(*layers)

    def forward(self, z: Tensor) -> Tensor:
        if z.dim() != 2 or z.shape[1] != self.in_channels:
            raise ValueError(f"z: expected (B, {self.in_channels}), got {tuple(z.shape)}")
        x = torch.relu(self.fc_norm(self.fc(z)))[:, :, None]  # B x 1024 x 1
        return self.deconvs(x).transpose(1, 2)  # B x 2048 x 3
