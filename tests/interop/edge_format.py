"""EDGE-format checkpoints made here, without EDGE's code: a parameter skeleton of EDGE's ``DanceDecoder`` (the
module tree of EDGE's model/model.py, with its attribute names and torch's own ``nn.MultiheadAttention``), random
weights, and its ``Normalizer``/``MinMaxScaler`` recreated under their EDGE module names so that the pickle names
``dataset.preprocess.Normalizer`` and ``dataset.scaler.MinMaxScaler`` exactly as EDGE's files do."""

from __future__ import annotations

import os
import sys
import types
from contextlib import contextmanager
from pathlib import Path

import torch
from torch import nn


class _Rotary(nn.Module):
    def __init__(self, dim: int) -> None:
        super().__init__()
        self.register_buffer("freqs", 1.0 / (10000 ** (torch.arange(0, dim, 2)[: dim // 2].float() / dim)))


class _Film(nn.Module):
    def __init__(self, d: int) -> None:
        super().__init__()
        self.block = nn.Sequential(nn.Mish(), nn.Linear(d, 2 * d))


class _EncoderLayer(nn.Module):
    def __init__(self, d: int, heads: int, ff: int, rotary: nn.Module) -> None:
        super().__init__()
        self.self_attn = nn.MultiheadAttention(d, heads, batch_first=True)
        self.linear1, self.linear2 = nn.Linear(d, ff), nn.Linear(ff, d)
        self.norm1, self.norm2 = nn.LayerNorm(d), nn.LayerNorm(d)
        self.rotary = rotary


class _DecoderLayer(_EncoderLayer):
    def __init__(self, d: int, heads: int, ff: int, rotary: nn.Module) -> None:
        super().__init__(d, heads, ff, rotary)
        self.multihead_attn = nn.MultiheadAttention(d, heads, batch_first=True)
        self.norm3 = nn.LayerNorm(d)
        self.film1, self.film2, self.film3 = _Film(d), _Film(d), _Film(d)


class _Stack(nn.Module):
    def __init__(self, layers: list[nn.Module]) -> None:
        super().__init__()
        self.stack = nn.ModuleList(layers)


class EdgeSkeleton(nn.Module):
    """The parameters of EDGE's DanceDecoder(nfeats=151, latent_dim=d, ff_size=ff, num_layers, num_heads,
    cond_feature_dim) under EDGE's names (no forward: the weights are what a checkpoint holds)."""

    def __init__(self, feature_dim: int, d: int = 32, layers: int = 2, heads: int = 8, ff: int = 64, seq: int = 150):
        super().__init__()
        self.rotary = _Rotary(d)
        self.abs_pos_encoding = nn.Identity()
        self.time_mlp = nn.Sequential(nn.Identity(), nn.Linear(d, 4 * d), nn.Mish())
        self.to_time_cond = nn.Sequential(nn.Linear(4 * d, d))
        self.to_time_tokens = nn.Sequential(nn.Linear(4 * d, 2 * d), nn.Identity())
        self.null_cond_embed = nn.Parameter(torch.randn(1, seq, d))
        self.null_cond_hidden = nn.Parameter(torch.randn(1, d))
        self.norm_cond = nn.LayerNorm(d)
        self.input_projection = nn.Linear(151, d)
        self.cond_encoder = nn.Sequential(*(_EncoderLayer(d, heads, ff, self.rotary) for _ in range(2)))
        self.cond_projection = nn.Linear(feature_dim, d)
        self.non_attn_cond_projection = nn.Sequential(nn.LayerNorm(d), nn.Linear(d, d), nn.SiLU(), nn.Linear(d, d))
        self.seqTransDecoder = _Stack([_DecoderLayer(d, heads, ff, self.rotary) for _ in range(layers)])
        self.final_layer = nn.Linear(d, 151)


@contextmanager
def edge_modules():
    """While inside: modules ``dataset.preprocess`` and ``dataset.scaler`` with EDGE's class names, for pickling."""
    saved = {k: sys.modules.get(k) for k in ("dataset", "dataset.preprocess", "dataset.scaler")}
    package, preprocess, scaler = (types.ModuleType(k) for k in saved)
    package.__path__ = []

    class MinMaxScaler:
        def __init__(self, feature_range=(0, 1), *, copy=True, clip=False):
            self.feature_range, self.copy, self.clip = feature_range, copy, clip

    class Normalizer:
        pass

    MinMaxScaler.__module__, Normalizer.__module__ = "dataset.scaler", "dataset.preprocess"
    MinMaxScaler.__qualname__, Normalizer.__qualname__ = "MinMaxScaler", "Normalizer"
    scaler.MinMaxScaler, preprocess.Normalizer = MinMaxScaler, Normalizer
    sys.modules.update({"dataset": package, "dataset.preprocess": preprocess, "dataset.scaler": scaler})
    try:
        yield Normalizer, MinMaxScaler
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v


def fitted_normalizer(Normalizer, MinMaxScaler, data: torch.Tensor):
    """EDGE's Normalizer(data) as its fit leaves it: per-channel min-max to (-1, 1), range 1 where it is zero."""
    flat = data.reshape(-1, data.shape[-1])
    scaler = MinMaxScaler((-1, 1), clip=True)
    data_min, data_max = flat.min(dim=0).values, flat.max(dim=0).values
    data_range = data_max - data_min
    scale = 2.0 / torch.where(
        data_range < 10 * torch.finfo(data_range.dtype).eps, torch.ones_like(data_range), data_range
    )
    scaler.n_samples_seen_ = flat.shape[0]
    scaler.scale_, scaler.min_ = scale, -1.0 - data_min * scale
    scaler.data_min_, scaler.data_max_, scaler.data_range_ = data_min, data_max, data_range
    normalizer = Normalizer()
    normalizer.scaler = scaler
    return normalizer


def motion_data(n: int = 8, seq: int = 150, seed: int = 0) -> torch.Tensor:
    """Plausible unnormalised 151-d frames: binary contacts, root near 0.9 m height, 6D rotations near identity."""
    g = torch.Generator().manual_seed(seed)
    x = torch.zeros(n, seq, 151)
    x[..., :4] = (torch.rand(n, seq, 4, generator=g) > 0.5).float()
    x[..., 4:7] = 0.3 * torch.randn(n, seq, 3, generator=g)
    x[..., 6] += 0.9
    identity = torch.tensor([1.0, 0, 0, 0, 1, 0])
    x[..., 7:] = identity.repeat(24) + 0.2 * torch.randn(n, seq, 144, generator=g)
    x[..., 10] = 1.0  # one constant channel: EDGE gives it range 1
    return x


def write_edge_checkpoint(
    path: Path, feature_dim: int = 35, *, prefix: bool = False, normalizer=None, seed: int = 0, **sizes
) -> dict[str, torch.Tensor]:
    """Write an EDGE-format checkpoint (random weights); returns the weights it holds (without prefix)."""
    torch.manual_seed(seed)
    state = EdgeSkeleton(feature_dim, **sizes).state_dict()
    with edge_modules() as (Normalizer, MinMaxScaler):
        if normalizer is None:
            normalizer = fitted_normalizer(Normalizer, MinMaxScaler, motion_data())
        elif callable(normalizer):
            normalizer = normalizer(Normalizer, MinMaxScaler)
        weights = {f"module.{k}" if prefix else k: v for k, v in state.items()}
        torch.save(
            {"ema_state_dict": weights, "model_state_dict": {k: v if k.endswith("freqs") else v + 1 for k, v in weights.items()},
             "optimizer_state_dict": {"state": {}}, "normalizer": normalizer},
            path,
        )  # fmt: skip
    return state


class RunsCode:
    """A pickle payload that runs a shell command when unpickled by anything that trusts the file."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))
