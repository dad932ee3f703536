"""Per-channel min-max normalisation to [-1, 1] (EDGE's, without its clipping), with plain-tensor state."""

from __future__ import annotations

import torch
from torch import nn


class MinMaxNormalizer(nn.Module):
    """Scales each channel from [min, max] of the training data to [-1, 1]; values outside stay outside.

    EDGE clips to [-1, 1] on the way back, which pins any value past the training range (a deeper level, a higher
    bounce) at its edge; here both directions are plain affine maps, exact inverses of each other. Channels with
    zero range get range 1 (so binary contacts 0/1 become -1/+1 and constant channels map to -1).
    State: buffers ``data_min`` and ``data_max`` (C,), saved with the model's state dict.
    """

    def __init__(self, num_channels: int) -> None:
        super().__init__()
        self.register_buffer("data_min", torch.zeros(num_channels))
        self.register_buffer("data_max", torch.ones(num_channels))
        self.register_buffer("fitted", torch.tensor(False))

    @torch.no_grad()
    def fit(self, data: torch.Tensor) -> MinMaxNormalizer:
        """Fit on data (..., C): every frame of the training set."""
        flat = data.reshape(-1, data.shape[-1]).to(self.data_min)
        self.data_min.copy_(flat.min(dim=0).values)
        self.data_max.copy_(flat.max(dim=0).values)
        self.fitted.fill_(True)
        return self

    def _range(self) -> torch.Tensor:
        rng = self.data_max - self.data_min
        return torch.where(rng > 0, rng, torch.ones_like(rng))

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.data_min) / self._range() * 2 - 1

    def unnormalize(self, y: torch.Tensor) -> torch.Tensor:
        return (y + 1) / 2 * self._range() + self.data_min

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.normalize(x)
