"""Ways to feed a style vector into the denoiser: style modulation (DGSDP Eq. 9) and concatenation.

Style modulation, DGSDP paper Eq. 9::

    SM(z, s) = z / (||z||_2 * r) * FC(s)

The paper calls ``r`` a scaling factor without giving it. With ``||z||_2`` the norm of each frame's feature
vector (size d) and ``r = d^-1/2``, ``z / (||z||_2 * r) = z * sqrt(d) / ||z||_2`` is exactly an RMS
normalisation without learned gain (unit root-mean-square per frame), the normalise-then-scale pattern of
adaptive instance normalisation that the paper cites as its inspiration; it is also what the official code
computes. We therefore use a per-frame norm over the feature axis and ``r = d^-1/2`` in both variants.

The variants differ in what the denoiser's decoder layer gets back (it calls the module between
cross-attention and the feed-forward block and uses the return value as the new hidden state):

* ``official``: the residual sum ``x + SM(x, s)``, as the official code does.
* ``paper``: Eq. 9 read literally, the modulated value ``SM(x, s)`` replaces ``x`` (no residual).
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import nn

ModulationVariant = Literal["official", "paper"]


class StyleModulation(nn.Module):
    """Scale the RMS-normalised hidden state by a learned projection of the style vector.

    ``FC`` is ``Linear(style_dim -> d_model)``. Style may be one vector per sequence ``(B, style_dim)`` or
    one per frame ``(B, T, style_dim)`` (style schedules that change over time).
    """

    def __init__(self, d_model: int, style_dim: int, variant: ModulationVariant = "official", eps: float = 1e-6):
        super().__init__()
        if variant not in ("official", "paper"):
            raise ValueError(f"Unknown style modulation variant {variant!r}; use 'official' or 'paper'.")
        if style_dim <= 0:
            raise ValueError("Style modulation needs a style vector (style_dim > 0); use style=none without it.")
        self.d_model = d_model
        self.style_dim = style_dim
        self.variant = variant
        self.eps = eps
        self.fc = nn.Linear(style_dim, d_model)

    def modulation(self, x: torch.Tensor, style: torch.Tensor) -> torch.Tensor:
        """``SM(x, s)``: ``x (B, T, d)``, ``style (B, ds)`` or ``(B, T, ds)`` -> ``(B, T, d)``."""
        if x.ndim != 3 or x.shape[-1] != self.d_model:
            raise ValueError(f"Expected hidden state (B, T, {self.d_model}), got {tuple(x.shape)}.")
        if style.shape[-1] != self.style_dim or style.ndim not in (2, 3):
            raise ValueError(
                f"Expected style (B, {self.style_dim}) or (B, T, {self.style_dim}), got {tuple(style.shape)}."
            )
        if style.ndim == 3 and style.shape[1] != x.shape[1]:
            raise ValueError(f"Per-frame style has {style.shape[1]} frames but the hidden state has {x.shape[1]}.")
        scale = self.fc(style.to(x.dtype))  # (B, d) or (B, T, d)
        if scale.ndim == 2:
            scale = scale.unsqueeze(1)  # broadcast over frames
        r = self.d_model**-0.5
        norm = x.norm(dim=-1, keepdim=True).clamp_min(self.eps)  # (B, T, 1)
        return x / (norm * r) * scale

    def forward(self, x: torch.Tensor, style: torch.Tensor) -> torch.Tensor:
        """New hidden state ``(B, T, d)``: ``x + SM(x, s)`` (official) or ``SM(x, s)`` (paper)."""
        modulated = self.modulation(x, style)
        return x + modulated if self.variant == "official" else modulated

    def extra_repr(self) -> str:
        return f"d_model={self.d_model}, style_dim={self.style_dim}, variant={self.variant}"


def concat_style(music: torch.Tensor, style: torch.Tensor) -> torch.Tensor:
    """Append the style to every music frame: ``music (B, T, Dm)``, ``style (B, ds)`` or ``(B, T, ds)``
    -> ``(B, T, Dm + ds)`` (the paper's "concat" injection; the official code also does it with modulation)."""
    if music.ndim != 3:
        raise ValueError(f"Expected music features (B, T, Dm), got {tuple(music.shape)}.")
    if style.ndim == 2:
        style = style.unsqueeze(1).expand(-1, music.shape[1], -1)
    if style.ndim != 3 or style.shape[:2] != music.shape[:2]:
        raise ValueError(f"Style {tuple(style.shape)} does not match music {tuple(music.shape)} in batch/frames.")
    return torch.cat([music, style.to(music.dtype)], dim=-1)
