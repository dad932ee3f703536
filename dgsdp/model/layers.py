"""Building blocks of the denoiser: rotary positions, attention, dropout, FiLM, sinusoidal time embedding."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


class RotaryEmbedding(nn.Module):
    """Rotary position embedding (RoPE) applied to queries and keys, per head, over frame positions.

    Applied per head to projected queries and keys, or to the layer input over the full width (EDGE); see
    :class:`Attention`.
    """

    def __init__(self, head_dim: int, base: float = 10000.0) -> None:
        super().__init__()
        if head_dim % 2:
            raise ValueError(f"rotary embedding needs an even head dimension, got {head_dim}")
        inv_freq = 1.0 / base ** (torch.arange(0, head_dim, 2, dtype=torch.float32) / head_dim)
        self.register_buffer("inv_freq", inv_freq, persistent=False)
        self._tables: dict[tuple, tuple[torch.Tensor, torch.Tensor]] = {}

    def tables(self, n: int, device: torch.device, dtype: torch.dtype) -> tuple[torch.Tensor, ...]:
        """The rotations of positions 0..n - 1: for a complex ``dtype``, one table (n, D/2) of unit complex numbers;
        else cos and signed sin (n, D), each pair's value repeated over its two channels and the sin negative on
        the first of them. Built once per length, device and dtype (not during training, where the buffers may
        still move)."""
        key = (n, device, dtype)
        cached = self._tables.get(key)
        if cached is not None and not self.training:
            return cached
        t = torch.arange(n, device=device, dtype=self.inv_freq.dtype)
        freqs = torch.outer(t, self.inv_freq.to(device))  # (T, Dh/2)
        if dtype.is_complex:
            tables = (torch.polar(torch.ones_like(freqs), freqs).to(dtype),)
        else:
            sin = freqs.sin()
            tables = (
                freqs.cos().repeat_interleave(2, dim=-1).to(dtype),
                torch.stack((-sin, sin), dim=-1).flatten(-2).to(dtype),
            )
        if not self.training:
            self._tables[key] = tables
        return tables

    def forward(self, x: torch.Tensor, start: int = 0) -> torch.Tensor:
        """x (..., T, D) -> same shape, rotated by position start..start + T - 1 (pairs of adjacent channels):
        (x1, x2) -> (x1 cos - x2 sin, x1 sin + x2 cos). In float32 and float64 that is one complex product per
        pair (a single pass, forward and backward: a fifth of the time of the real formula on a training batch);
        other dtypes (bf16 under autocast) take the real formula, x * cos + swapped(x) * signed sin."""
        n = start + x.shape[-2]
        pairs = x.unflatten(-1, (-1, 2))
        if (
            x.dtype in (torch.float32, torch.float64)
            and pairs.stride(-1) == 1
            and all(s % 2 == 0 for s in pairs.stride()[:-1])
        ):
            (rotation,) = self.tables(n, x.device, torch.complex64 if x.dtype == torch.float32 else torch.complex128)
            return torch.view_as_real(torch.view_as_complex(pairs) * rotation[start:]).flatten(-2)
        cos, sin = self.tables(n, x.device, x.dtype)
        return torch.addcmul(x * cos[start:], pairs.flip(-1).flatten(-2), sin[start:])


def dropout_mask(x: torch.Tensor, p: float, training: bool) -> tuple[torch.Tensor, float]:
    """Dropout with the kept elements' scale returned apart: ``(x with the dropped elements zeroed, factor)``, and
    ``dropout(x) = zeroed * factor``. A caller folds the factor into a product that follows for free (a matrix
    product's ``alpha``, FiLM's scale, a residual add's ``alpha``) instead of a pass over the tensor.

    torch draws a CPU dropout mask one float at a time (``bernoulli_``), which took a sixth of a paper-size
    training step on 2 cores. Here one 64-bit draw of torch's generator gives the masks of four elements (16 bits
    each): an element is dropped with probability ``round(p * 65536) / 65536`` (p = 0.1 -> 0.1000061) and the
    factor is the inverse of the kept probability, so the expectation is unchanged. Other devices use
    ``F.dropout`` (factor 1)."""
    if not training or p == 0.0:
        return x, 1.0
    if x.device.type != "cpu":
        return F.dropout(x, p, True), 1.0
    drop = round(p * 65536)
    if drop >= 65536:
        return x * 0.0, 1.0
    n = x.numel()
    bits = torch.empty((n + 3) // 4, dtype=torch.int64).random_(-(2**63), None).view(torch.int16)[:n]
    return torch.where(bits.view(x.shape) < drop - 32768, 0.0, x), 65536 / (65536 - drop)  # one pass, not two


def dropout(x: torch.Tensor, p: float, training: bool) -> torch.Tensor:
    """``F.dropout``, with :func:`dropout_mask`'s cheaper mask on CPU."""
    zeroed, factor = dropout_mask(x, p, training)
    return zeroed if factor == 1.0 else zeroed * factor


class Dropout(nn.Dropout):
    """``nn.Dropout`` through :func:`dropout` (its cheaper CPU mask); :meth:`mask` leaves the scale to the caller."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return dropout(x, self.p, self.training)

    def mask(self, x: torch.Tensor) -> tuple[torch.Tensor, float]:
        """:func:`dropout_mask` at this module's rate and mode."""
        return dropout_mask(x, self.p, self.training)


def linear(x: torch.Tensor, layer: nn.Linear, alpha: float = 1.0) -> torch.Tensor:
    """``layer(x * alpha)``, with ``alpha`` applied inside the matrix product (``addmm``'s) instead of on ``x``."""
    if alpha == 1.0:
        return layer(x)
    out = torch.addmm(layer.bias, x.reshape(-1, x.shape[-1]), layer.weight.t(), alpha=alpha)
    return out.view(*x.shape[:-1], out.shape[-1])


ROTARY_PLACEMENTS = ("qk", "input")


class Attention(nn.Module):
    """Multi-head attention through ``F.scaled_dot_product_attention``, with optional rotary positions.

    ``rotary_placement``: ``"qk"`` rotates the projected queries and keys per head (the standard formulation);
    ``"input"`` rotates the inputs of the query and key projections over the full width, as EDGE does (values
    come from the unrotated input). Either way the parameters are the same.
    """

    def __init__(self, d_model: int, n_heads: int, dropout: float, rotary: bool, rotary_placement: str = "qk") -> None:
        super().__init__()
        if d_model % n_heads:
            raise ValueError(f"width {d_model} is not divisible by {n_heads} heads")
        if rotary_placement not in ROTARY_PLACEMENTS:
            raise ValueError(f"unknown rotary placement {rotary_placement!r}; use one of {ROTARY_PLACEMENTS}")
        self.n_heads = n_heads
        self.q = nn.Linear(d_model, d_model)
        self.kv = nn.Linear(d_model, 2 * d_model)
        self.out = nn.Linear(d_model, d_model)
        self.dropout = dropout
        self.rotary_placement = rotary_placement
        width = d_model // n_heads if rotary_placement == "qk" else d_model
        self.rotary = RotaryEmbedding(width) if rotary else None

    def _heads(self, x: torch.Tensor) -> torch.Tensor:
        b, t, d = x.shape
        return x.view(b, t, self.n_heads, d // self.n_heads).transpose(1, 2)

    def keys_values(self, src: torch.Tensor, start: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
        """Keys and values (B, H, S, Dh) of ``src`` (B, S, d) at positions start..start + S - 1 (the keys are
        rotated when the attention has rotary positions; values never are). Computed once, they serve every
        query: a memory's keys and values are cached for a whole sampling run this way."""
        if self.rotary is not None and self.rotary_placement == "input":
            w_k, w_v = self.kv.weight.chunk(2, dim=0)
            b_k, b_v = self.kv.bias.chunk(2)
            return self._heads(F.linear(self.rotary(src, start), w_k, b_k)), self._heads(F.linear(src, w_v, b_v))
        k, v = self.kv(src).chunk(2, dim=-1)
        k, v = self._heads(k), self._heads(v)
        return (k if self.rotary is None else self.rotary(k, start)), v

    def queries(self, x: torch.Tensor) -> torch.Tensor:
        """Queries (B, H, T, Dh) of ``x`` (B, T, d) at positions 0..T - 1."""
        if self.rotary is None:
            return self._heads(self.q(x))
        if self.rotary_placement == "input":
            return self._heads(self.q(self.rotary(x)))
        return self.rotary(self._heads(self.q(x)))

    def _self_qkv(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Queries, keys and values of self-attention, from one projection (queries and keys from one where the
        input is rotated; the rotation computed once): the same values as :meth:`queries` and
        :meth:`keys_values`, in fewer and larger matrix products."""
        d = x.shape[-1]
        if self.rotary is not None and self.rotary_placement == "input":
            w_v, b_v = self.kv.weight[d:], self.kv.bias[d:]
            w_qk = torch.cat((self.q.weight, self.kv.weight[:d]))
            q, k = F.linear(self.rotary(x), w_qk, torch.cat((self.q.bias, self.kv.bias[:d]))).chunk(2, dim=-1)
            return self._heads(q), self._heads(k), self._heads(F.linear(x, w_v, b_v))
        w = torch.cat((self.q.weight, self.kv.weight))
        q, k, v = (self._heads(y) for y in F.linear(x, w, torch.cat((self.q.bias, self.kv.bias))).chunk(3, dim=-1))
        if self.rotary is not None:
            q, k = self.rotary(q), self.rotary(k)
        return q, k, v

    def forward(
        self,
        x: torch.Tensor,
        memory: torch.Tensor | None = None,
        kv: tuple[torch.Tensor, torch.Tensor] | None = None,
        shared_rows: int = 0,
    ) -> torch.Tensor:
        """x (B, T, d) attends to ``memory`` (B, S, d), or to itself if None; or to keys and values ``kv``
        computed earlier by :meth:`keys_values`. Queries sit at positions 0..T - 1, memory at 0..S - 1.
        ``shared_rows`` = s > 0 (with ``kv``): the first s rows of x share row 0 of the keys and values; rows
        1.. belong to rows s.. of x."""
        if memory is None and kv is None:
            q, k, v = self._self_qkv(x)
        else:
            q = self.queries(x)
            k, v = kv if kv is not None else self.keys_values(memory)
        if shared_rows:
            s = shared_rows
            first = F.scaled_dot_product_attention(q[:s], k[:1].expand(s, -1, -1, -1), v[:1].expand(s, -1, -1, -1))
            y = torch.cat((first, F.scaled_dot_product_attention(q[s:], k[1:], v[1:]))) if len(k) > 1 else first
            return self.out(y.transpose(1, 2).flatten(2))
        if self.training and self.dropout and q.device.type == "cpu":
            # SDPA would draw its attention-weight dropout mask with bernoulli_ (see :func:`dropout`)
            weights = torch.softmax((q * q.shape[-1] ** -0.5) @ k.transpose(-2, -1), dim=-1).to(v.dtype)
            zeroed, factor = dropout_mask(weights, self.dropout, True)  # in v's precision (bf16 under autocast)
            return linear((zeroed @ v).transpose(1, 2).flatten(2), self.out, factor)  # out(factor * y)
        y = F.scaled_dot_product_attention(q, k, v, dropout_p=self.dropout if self.training else 0.0)
        return self.out(y.transpose(1, 2).flatten(2))


class FeedForward(nn.Sequential):
    def __init__(self, d_model: int, ff_dim: int, dropout: float) -> None:
        super().__init__(nn.Linear(d_model, ff_dim), nn.GELU(), Dropout(dropout), nn.Linear(ff_dim, d_model))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Linear, GELU, dropout, Linear; the dropout's scale applied inside the second product."""
        zeroed, factor = self[2].mask(self[1](self[0](x)))
        return linear(zeroed, self[3], factor)


class FiLM(nn.Module):
    """Feature-wise linear modulation by the time condition: h * (1 + scale) + shift."""

    def __init__(self, d_model: int) -> None:
        super().__init__()
        self.proj = nn.Sequential(nn.Mish(), nn.Linear(d_model, 2 * d_model))

    def forward(self, h: torch.Tensor, cond: torch.Tensor, factor: float = 1.0) -> torch.Tensor:
        """h (B, T, d), cond (B, d) or per frame (B, T, d) -> FiLM of ``h * factor`` (a dropout's scale, see
        :func:`dropout_mask`)."""
        params = self.proj(cond)
        scale, shift = (params if params.ndim == 3 else params.unsqueeze(1)).chunk(2, dim=-1)
        return torch.addcmul(shift, h, (1 + scale) * factor)


class EncoderLayer(nn.Module):
    """Pre-norm transformer encoder layer with rotary self-attention (the music encoder)."""

    def __init__(self, d_model: int, n_heads: int, ff_dim: int, dropout: float, rotary_placement: str = "qk") -> None:
        super().__init__()
        self.norm1, self.norm2 = nn.LayerNorm(d_model), nn.LayerNorm(d_model)
        self.attn = Attention(d_model, n_heads, dropout, rotary=True, rotary_placement=rotary_placement)
        self.ff = FeedForward(d_model, ff_dim, dropout)
        self.drop = Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self._residual(x, self.attn(self.norm1(x)))
        return self._residual(x, self.ff(self.norm2(x)))

    def _residual(self, x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """``x + dropout(h)``, the dropout's scale applied in the add."""
        zeroed, factor = self.drop.mask(h)
        return x.add(zeroed, alpha=factor)


def sinusoidal_embedding(t: torch.Tensor, dim: int) -> torch.Tensor:
    """Diffusion step t (B,) -> (B, dim) sinusoidal features."""
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, device=t.device, dtype=torch.float32) / (half - 1))
    args = t.float()[:, None] * freqs[None]
    return torch.cat((args.sin(), args.cos()), dim=-1)
