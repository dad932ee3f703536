"""The denoiser: EDGE's DanceDecoder extended with style (DGSDP's MCSAD).

Given a noisy motion x_t (B, T, 151), the diffusion step t, music features (B, T, Da) and a style vector, it
predicts the clean motion x0 (B, T, 151).

- Time: sinusoidal -> Linear(d, 4d) -> Mish; Linear(4d, d) gives the FiLM vector, Linear(4d, 2d) two time tokens.
- Music: Linear(Da, d) (plus Linear(ds, d) of the style in ``concat`` injection: a linear layer over the
  concatenation [music, style] is exactly the sum of the two projections), a 2-layer rotary transformer
  encoder, tokens mean-pooled -> LN -> Linear -> SiLU -> Linear added to the FiLM vector.
- Condition dropout for classifier-free guidance: a dropped music input is replaced by a learned null sequence
  (before the music encoder; EDGE replaces the encoder output, which is an equally free learned constant when no
  style is concatenated), a dropped style by a learned null style vector. Music and style drop separately.
- Cross-attention memory: LayerNorm(concat(music tokens, time tokens)).
- Decoder layer: pre-norm self-attention, cross-attention, [style modulation], feed-forward; each sub-block's
  output passes FiLM by the time vector before the residual add.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from dgsdp.model.layers import Attention, EncoderLayer, FeedForward, FiLM, sinusoidal_embedding
from dgsdp.style.injection import StyleModulation

INJECTIONS = ("modulation", "concat")


@dataclass
class DenoiserCondition:
    """What the denoiser derives from music and style alone, computed once per sampling run by
    :meth:`DanceDenoiser.condition` and reused at every step.

    style: the style after condition dropout (B, ds) or (B, T, ds), or None; pooled: (B, d), the pooled music
    tokens added to the FiLM vector; keys, values: per decoder layer (B, H, T + 2, Dh), the cross-attention keys
    and values of the memory, whose last two positions (the time tokens) are filled in at every step.
    """

    style: torch.Tensor | None
    pooled: torch.Tensor
    keys: list[torch.Tensor]
    values: list[torch.Tensor]
    n_frames: int

    @property
    def batch_size(self) -> int:
        return self.pooled.shape[0]

    def rows(self, sl: slice) -> DenoiserCondition:
        """The condition of rows ``sl`` (views, no copies)."""
        return DenoiserCondition(
            None if self.style is None else self.style[sl],
            self.pooled[sl],
            [k[sl] for k in self.keys],
            [v[sl] for v in self.values],
            self.n_frames,
        )


class DecoderLayer(nn.Module):
    def __init__(self, d_model: int, n_heads: int, ff_dim: int, dropout: float) -> None:
        super().__init__()
        self.norm1, self.norm2, self.norm3 = (
            nn.LayerNorm(d_model),
            nn.LayerNorm(d_model),
            nn.LayerNorm(d_model),
        )
        self.self_attn = Attention(d_model, n_heads, dropout, rotary=True)
        self.cross_attn = Attention(d_model, n_heads, dropout, rotary=False)
        self.ff = FeedForward(d_model, ff_dim, dropout)
        self.film1, self.film2, self.film3 = FiLM(d_model), FiLM(d_model), FiLM(d_model)
        self.drop = nn.Dropout(dropout)

    def forward(
        self,
        x: torch.Tensor,
        memory: torch.Tensor | None,
        t_cond: torch.Tensor,
        style: torch.Tensor | None = None,
        modulation: StyleModulation | None = None,
        memory_kv: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """``memory`` (B, S, d), or its cross-attention keys and values ``memory_kv`` computed earlier."""
        x = x + self.drop(self.film1(self.self_attn(self.norm1(x)), t_cond))
        x = x + self.drop(self.film2(self.cross_attn(self.norm2(x), memory, kv=memory_kv), t_cond))
        if modulation is not None and style is not None:
            x = modulation(x, style)
        return x + self.drop(self.film3(self.ff(self.norm3(x)), t_cond))


class DanceDenoiser(nn.Module):
    """Predicts x0 from (x_t, t, music, style). All sizes come from config (``conf/model``)."""

    def __init__(
        self,
        *,
        pose_dim: int = 151,
        seq_len: int = 150,
        d_model: int = 512,
        n_layers: int = 8,
        n_heads: int = 8,
        ff_dim: int = 1024,
        dropout: float = 0.1,
        audio_dim: int = 35,
        music_encoder_layers: int = 2,
        style_dim: int = 0,
        style_injection: str = "modulation",
        modulation_variant: str = "official",
        modulation_shared: bool = True,
        also_concat: bool = False,
    ) -> None:
        super().__init__()
        if style_dim and style_injection not in INJECTIONS:
            raise ValueError(f"unknown style injection {style_injection!r}; use one of {INJECTIONS}")
        self.pose_dim, self.seq_len, self.d_model = pose_dim, seq_len, d_model
        self.audio_dim, self.style_dim = audio_dim, style_dim
        self.use_modulation = bool(style_dim) and style_injection == "modulation"
        self.use_concat = bool(style_dim) and (style_injection == "concat" or also_concat)

        self.input_proj = nn.Linear(pose_dim, d_model)
        self.time_mlp = nn.Sequential(nn.Linear(d_model, 4 * d_model), nn.Mish())
        self.time_film = nn.Linear(4 * d_model, d_model)
        self.time_tokens = nn.Linear(4 * d_model, 2 * d_model)

        self.music_proj = nn.Linear(audio_dim, d_model) if audio_dim else None
        self.null_music = nn.Parameter(torch.randn(1, seq_len, d_model) * 0.02)
        self.style_concat_proj = nn.Linear(style_dim, d_model, bias=False) if self.use_concat else None
        self.null_style = nn.Parameter(torch.zeros(style_dim)) if style_dim else None
        self.music_encoder = nn.Sequential(
            *(EncoderLayer(d_model, n_heads, ff_dim, dropout) for _ in range(music_encoder_layers))
        )
        self.music_pool = nn.Sequential(
            nn.LayerNorm(d_model), nn.Linear(d_model, d_model), nn.SiLU(), nn.Linear(d_model, d_model)
        )
        self.memory_norm = nn.LayerNorm(d_model)

        self.layers = nn.ModuleList(DecoderLayer(d_model, n_heads, ff_dim, dropout) for _ in range(n_layers))
        self.modulations: nn.ModuleList | None = None
        if self.use_modulation:
            count = 1 if modulation_shared else n_layers
            self.modulations = nn.ModuleList(
                StyleModulation(d_model, style_dim, variant=modulation_variant) for _ in range(count)
            )
        self.output_proj = nn.Linear(d_model, pose_dim)

    def _style(self, style: torch.Tensor | None, keep: torch.Tensor, batch: int) -> torch.Tensor | None:
        if not self.style_dim:
            return None
        null = self.null_style.expand(batch, self.style_dim)
        if style is None:
            return null
        if style.ndim == 3:  # per-frame style (B, T, ds)
            return torch.where(keep[:, None, None], style, null[:, None, :])
        return torch.where(keep[:, None], style, null)

    def _music_tokens(
        self,
        music: torch.Tensor | None,
        style: torch.Tensor | None,
        keep_music: torch.Tensor,
        keep_style: torch.Tensor,
        n: int,
        *,
        project_kept_only: bool = False,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Music encoder output (B, n, d) and the style after dropout. ``project_kept_only``: run ``music_proj``
        on the rows whose music is kept only (one host sync to find them; for once-per-run conditioning)."""
        b = keep_music.shape[0]
        null = self.null_music[:, :n].expand(b, -1, -1)
        if music is None or self.music_proj is None:
            h_music = null
        else:
            if music.shape[:2] != (b, n) or music.shape[-1] != self.audio_dim:
                raise ValueError(f"music features {tuple(music.shape)} do not match ({b}, {n}, {self.audio_dim})")
            if project_kept_only:
                rows = keep_music.nonzero().squeeze(1)
                projected = self.music_proj(music[rows])
                h_music = null.to(projected.dtype).clone(memory_format=torch.contiguous_format)
                h_music.index_copy_(0, rows, projected)
            else:
                h_music = torch.where(keep_music[:, None, None], self.music_proj(music), null)
        s = self._style(style, keep_style, b)
        if self.style_concat_proj is not None:
            h_style = self.style_concat_proj(s)
            h_music = h_music + (h_style if h_style.ndim == 3 else h_style[:, None, :])
        return self.music_encoder(h_music), s

    def _keep(self, keep: torch.Tensor | None, b: int, device: torch.device) -> torch.Tensor:
        return torch.ones(b, dtype=torch.bool, device=device) if keep is None else keep

    @torch.no_grad()
    def condition(
        self,
        music: torch.Tensor | None,
        style: torch.Tensor | None,
        keep_music: torch.Tensor | None = None,
        keep_style: torch.Tensor | None = None,
        *,
        n_frames: int | None = None,
        batch: int | None = None,
    ) -> DenoiserCondition:
        """The conditioning of ``forward(x_t, t, cond=...)`` for music (B, T, Da) and style, computed once for a
        whole sampling run: music encoder, pooled music, style, and the cross-attention keys and values of the
        music tokens. The rows' batch and length come from the music (or from ``batch`` / ``n_frames``)."""
        if music is not None:
            batch, n_frames = music.shape[0], music.shape[1]
        if batch is None:
            batch = keep_music.shape[0] if keep_music is not None else style.shape[0] if style is not None else None
        if batch is None or n_frames is None:
            raise ValueError("condition() needs the batch size and the number of frames when there is no music")
        if n_frames > self.seq_len:
            raise ValueError(f"sequence of {n_frames} frames is longer than the model's {self.seq_len}; use long-form")
        device = self.null_music.device
        keep_music = self._keep(keep_music, batch, device)
        keep_style = self._keep(keep_style, batch, device)
        tokens, s = self._music_tokens(music, style, keep_music, keep_style, n_frames, project_kept_only=True)
        pooled = self.music_pool(tokens.mean(dim=1))
        memory = self.memory_norm(tokens)  # LayerNorm is per token: the time tokens are normalised per step
        keys, values = [], []
        for layer in self.layers:
            k, v = layer.cross_attn.keys_values(memory)
            shape = (*k.shape[:2], n_frames + 2, k.shape[-1])
            k_all, v_all = k.new_empty(shape), v.new_empty(shape)
            k_all[:, :, :n_frames], v_all[:, :, :n_frames] = k, v
            keys.append(k_all)
            values.append(v_all)
        return DenoiserCondition(s, pooled, keys, values, n_frames)

    def forward(
        self,
        x_t: torch.Tensor,
        t: torch.Tensor,
        music: torch.Tensor | None = None,
        style: torch.Tensor | None = None,
        keep_music: torch.Tensor | None = None,
        keep_style: torch.Tensor | None = None,
        *,
        cond: DenoiserCondition | None = None,
    ) -> torch.Tensor:
        """x_t (B, T, 151), t (B,), music (B, T, Da), style (B, ds) or (B, T, ds); keep_* (B,) bool
        (False = condition dropped); or, instead of music, style and keep_*, ``cond`` from :meth:`condition`
        (sampling). Returns x0 prediction (B, T, 151)."""
        b, n, _ = x_t.shape
        if n > self.seq_len:
            raise ValueError(f"sequence of {n} frames is longer than the model's {self.seq_len}; use long-form")
        t_hidden = self.time_mlp(sinusoidal_embedding(t, self.d_model))
        t_cond = self.time_film(t_hidden)
        t_tokens = self.time_tokens(t_hidden).view(b, 2, self.d_model)
        if cond is not None:
            return self._forward_cached(x_t, t_cond, t_tokens, cond)

        keep_music = self._keep(keep_music, b, x_t.device)
        keep_style = self._keep(keep_style, b, x_t.device)
        tokens, s = self._music_tokens(music, style, keep_music, keep_style, n)
        t_cond = t_cond + self.music_pool(tokens.mean(dim=1))
        memory = self.memory_norm(torch.cat((tokens, t_tokens), dim=1))

        h = self.input_proj(x_t)
        for i, layer in enumerate(self.layers):
            h = layer(h, memory, t_cond, s, self._modulation(i))
        return self.output_proj(h)

    def _modulation(self, i: int) -> StyleModulation | None:
        return None if self.modulations is None else self.modulations[min(i, len(self.modulations) - 1)]

    def _forward_cached(
        self, x_t: torch.Tensor, t_cond: torch.Tensor, t_tokens: torch.Tensor, cond: DenoiserCondition
    ) -> torch.Tensor:
        b, n, _ = x_t.shape
        if (cond.batch_size, cond.n_frames) != (b, n):
            raise ValueError(
                f"the conditioning is for {cond.batch_size} rows of {cond.n_frames} frames, not ({b}, {n})"
            )
        t_cond = t_cond + cond.pooled
        t_memory = self.memory_norm(t_tokens)
        h = self.input_proj(x_t)
        for i, layer in enumerate(self.layers):
            keys, values = cond.keys[i], cond.values[i]
            # the time tokens' keys and values go into the last two positions of the cached memory
            keys[:, :, n:], values[:, :, n:] = layer.cross_attn.keys_values(t_memory)
            h = layer(h, None, t_cond, cond.style, self._modulation(i), memory_kv=(keys, values))
        return self.output_proj(h)
