"""The denoiser: EDGE's DanceDecoder extended with style (DGSDP's MCSAD).

Given a noisy motion x_t (B, T, pose_dim) (SMPL-24: 151), the diffusion step t, music features (B, T, Da) and a style
vector, it predicts the clean motion x0 (B, T, pose_dim).

- Time: sinusoidal -> Linear(d, 4d) -> Mish; Linear(4d, d) gives the FiLM vector, Linear(4d, 2d) two time tokens.
- Music: Linear(Da, d) (plus Linear(ds, d) of the style in ``concat`` injection: a linear layer over the
  concatenation [music, style] is exactly the sum of the two projections), a 2-layer rotary transformer
  encoder, tokens mean-pooled -> LN -> Linear -> SiLU -> Linear added to the FiLM vector.
- Condition dropout for classifier-free guidance: a dropped style is a learned null style vector. A dropped music
  input is, with ``null_music="input"`` (default), a learned null sequence before the music encoder, so a style
  concatenated to the music survives a dropped music and the two drop separately; with ``"output"`` (EDGE), a
  learned null sequence replaces the encoder's output tokens and a learned null vector (d parameters) the pooled
  vector, which also drops a concatenated style with the music.
- Cross-attention memory: LayerNorm(concat(music tokens, time tokens)).
- Decoder layer: pre-norm self-attention, cross-attention, [style modulation], feed-forward; each sub-block's
  output passes dropout, then FiLM by the time vector, before the residual add (EDGE's order).
- Rotary positions in every self-attention, on projected queries and keys per head (``rotary_placement="qk"``,
  default) or on the layer input over the full width (``"input"``, EDGE); and in the cross-attention
  (``cross_attention_rotary``, default, as EDGE: motion positions 0..149 for queries, memory positions 0..149
  music, 150..151 time tokens for keys), so that frame i of the motion attends to the music around frame i.
  Without it neither stream carries positions into the cross-attention: every frame sees the music as an
  unordered set, and no dance can land on a beat (runs from before the switch were trained that way and load so).
- ``guidance_inputs`` (a guidance-distilled student, :mod:`dgsdp.training.distill`): the classifier-free guidance
  weights (music, and style for models with style guidance) are an input, embedded like the diffusion step and
  added to its embedding, so that one pass predicts what the teacher's guided passes would. The projection starts
  at zero: an untrained student is its teacher's conditional model.
- ``gradient_checkpointing`` recomputes each encoder/decoder layer's activations in the backward pass (less
  memory for long windows, about a third more compute).
- ``movement_channels`` (in neither paper; :mod:`dgsdp.style.movement`): the style vector has one more channel per
  measured attribute of the dance (its mean joint speed, level, arms, travel, turning; encoded scale-free over the
  training windows: :meth:`dgsdp.trained.TrainedModel.movement_encoding`), which enter every decoder layer with the
  style (Style Modulation, and wherever else the style goes) and drop with it. ``speed_conditioning=True`` is the
  same as listing ``speed``.

The EDGE architecture is ``rotary_placement="input", null_music="output"`` (see docs/edge.md).

Sampling computes what depends on music and style alone once per run (:meth:`DanceDenoiser.condition`: the
music encoder, the pooled music vector, the style after dropout, and the cross-attention keys and values of the
music tokens) and passes it to every step as ``forward(x_t, t, cond=...)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import nn
from torch.utils.checkpoint import checkpoint

from dgsdp.model.layers import Attention, Dropout, EncoderLayer, FeedForward, FiLM, sinusoidal_embedding
from dgsdp.style.injection import StyleModulation
from dgsdp.style.movement import movement_channels as resolve_movement_channels

INJECTIONS = ("modulation", "concat")
NULL_MUSIC = ("input", "output")
GUIDANCE_INPUTS = (0, 1, 2)
GUIDANCE_SCALE = 100.0  # guidance weights are embedded like diffusion steps of 100 w


@dataclass
class DenoiserCondition:
    """What the denoiser derives from music and style alone, computed once per sampling run by
    :meth:`DanceDenoiser.condition` and reused at every step.

    style: the style after condition dropout (B, ds) or (B, T, ds), or None; pooled: (B, d), the pooled music
    tokens added to the FiLM vector; keys, values: per decoder layer (B, H, T + 2, Dh), the cross-attention keys
    (rotated to their positions when the cross-attention has rotary positions) and values of the memory, whose
    last two positions (the time tokens) are filled in at every step. ``shared_rows`` = s > 0: the first s rows
    have dropped music and the same memory (the null music, which no style enters), and their keys and values are
    stored once, as row 0 of ``keys`` and ``values`` (rows 1.. are rows s.. of the batch): for a whole song this
    saves the unconditional pass's copy of the cache, half of it.
    """

    style: torch.Tensor | None
    pooled: torch.Tensor
    keys: list[torch.Tensor]
    values: list[torch.Tensor]
    n_frames: int
    aligned: torch.Tensor | None = None  # (B, T, d) the music added to each frame's motion token (aligned_music)
    shared_rows: int = 0

    @property
    def batch_size(self) -> int:
        return self.pooled.shape[0]


class DecoderLayer(nn.Module):
    def __init__(
        self,
        d_model: int,
        n_heads: int,
        ff_dim: int,
        dropout: float,
        *,
        rotary_placement: str = "qk",
        cross_attention_rotary: bool = True,
    ) -> None:
        super().__init__()
        self.norm1, self.norm2, self.norm3 = (
            nn.LayerNorm(d_model),
            nn.LayerNorm(d_model),
            nn.LayerNorm(d_model),
        )
        self.self_attn = Attention(d_model, n_heads, dropout, rotary=True, rotary_placement=rotary_placement)
        self.cross_attn = Attention(
            d_model, n_heads, dropout, rotary=cross_attention_rotary, rotary_placement=rotary_placement
        )
        self.ff = FeedForward(d_model, ff_dim, dropout)
        self.film1, self.film2, self.film3 = FiLM(d_model), FiLM(d_model), FiLM(d_model)
        self.drop = Dropout(dropout)

    def forward(
        self,
        x: torch.Tensor,
        memory: torch.Tensor | None,
        t_cond: torch.Tensor,
        style: torch.Tensor | None = None,
        modulation: StyleModulation | None = None,
        memory_kv: tuple[torch.Tensor, torch.Tensor] | None = None,
        shared_rows: int = 0,
    ) -> torch.Tensor:
        """``memory`` (B, S, d), or its cross-attention keys and values ``memory_kv`` computed earlier (the first
        ``shared_rows`` rows' stored once, see :class:`DenoiserCondition`)."""
        x = x + self._film(self.film1, self.self_attn(self.norm1(x)), t_cond)
        cross = self.cross_attn(self.norm2(x), memory, kv=memory_kv, shared_rows=shared_rows)
        x = x + self._film(self.film2, cross, t_cond)
        if modulation is not None and style is not None:
            x = modulation(x, style)
        return x + self._film(self.film3, self.ff(self.norm3(x)), t_cond)

    def _film(self, film: FiLM, h: torch.Tensor, t_cond: torch.Tensor) -> torch.Tensor:
        """``film(dropout(h))``, the dropout's scale applied in FiLM's (see :func:`dropout_mask`)."""
        zeroed, factor = self.drop.mask(h)
        return film(zeroed, t_cond, factor)


def _rows_of(music: torch.Tensor, rows: torch.Tensor, music_rows: torch.Tensor | None) -> torch.Tensor:
    """The music features of batch rows ``rows``: ``music[rows]``, or ``music[music_rows[rows]]`` when
    ``music_rows`` names each row's music (see :meth:`DanceDenoiser.condition`)."""
    return music[rows if music_rows is None else music_rows[rows]]


class DanceDenoiser(nn.Module):
    """Predicts x0 from (x_t, t, music, style). All sizes come from config (``conf/model``)."""

    # Settings added after runs were first trained, with the value those runs used (see dgsdp.registry.build):
    # runs from before the switch had no positions in their cross-attention.
    legacy_settings: ClassVar[dict[str, Any]] = {"cross_attention_rotary": False}

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
        rotary_placement: str = "qk",
        cross_attention_rotary: bool = True,
        null_music: str = "input",
        aligned_music: bool = False,
        style_film: bool = False,
        style_standardize: float | None = None,
        guidance_inputs: int = 0,
        gradient_checkpointing: bool = False,
        speed_conditioning: bool = False,
        movement_channels: Sequence[str] = (),
    ) -> None:
        super().__init__()
        self.movement_channels = resolve_movement_channels(movement_channels, speed_conditioning)
        if self.movement_channels and not style_dim:
            raise ValueError(
                "movement channels (model.movement_channels, model.speed_conditioning) travel with the style: they "
                "need a model with style (style_dim > 0)"
            )
        if style_dim and style_injection not in INJECTIONS:
            raise ValueError(f"unknown style injection {style_injection!r}; use one of {INJECTIONS}")
        if null_music not in NULL_MUSIC:
            raise ValueError(f"unknown null_music {null_music!r}; use one of {NULL_MUSIC}")
        if guidance_inputs not in GUIDANCE_INPUTS:
            raise ValueError(f"guidance_inputs must be one of {GUIDANCE_INPUTS}, got {guidance_inputs!r}")
        if style_standardize is not None and not (0 < style_standardize <= 100):
            raise ValueError(f"style_standardize must be a number in (0, 100] or null, got {style_standardize!r}")
        self.null_music_at = null_music
        self.gradient_checkpointing = gradient_checkpointing
        self.pose_dim, self.seq_len, self.d_model = pose_dim, seq_len, d_model
        self.audio_dim, self.style_dim = audio_dim, style_dim
        style_in = self.style_in = style_dim + len(self.movement_channels)  # the style vector's channels
        self.use_modulation = bool(style_dim) and style_injection == "modulation"
        self.use_concat = bool(style_dim) and (style_injection == "concat" or also_concat)

        self.input_proj = nn.Linear(pose_dim, d_model)
        self.time_mlp = nn.Sequential(nn.Linear(d_model, 4 * d_model), nn.Mish())
        self.time_film = nn.Linear(4 * d_model, d_model)
        self.time_tokens = nn.Linear(4 * d_model, 2 * d_model)
        self.guidance_inputs = guidance_inputs
        self.guidance_proj: nn.Linear | None = None
        if guidance_inputs:  # zero-initialised: the student starts as its teacher's conditional model
            self.guidance_proj = nn.Linear(guidance_inputs * d_model, d_model)
            nn.init.zeros_(self.guidance_proj.weight)
            nn.init.zeros_(self.guidance_proj.bias)

        self.music_proj = nn.Linear(audio_dim, d_model) if audio_dim else None
        self.null_music = nn.Parameter(torch.randn(1, seq_len, d_model) * 0.02)
        # EDGE: a learned null for the pooled music vector too (the null token sequence replaces the encoder output)
        self.null_music_hidden = nn.Parameter(torch.randn(1, d_model) * 0.02) if null_music == "output" else None
        self.style_concat_proj = nn.Linear(style_in, d_model, bias=False) if self.use_concat else None
        self.null_style = nn.Parameter(torch.zeros(style_in)) if style_dim else None
        # style in every FiLM too (in neither paper): the style's projection joins the diffusion step's condition,
        # which scales and shifts every sub-block of every decoder layer
        self.style_film_proj = nn.Linear(style_in, d_model) if style_dim and style_film else None
        # style standardisation (in neither paper): every style vector, free text included, is centred on the training
        # style bank's mean and scaled to a per-dimension root mean square of ``style_standardize``, so that what
        # tells the genres apart, not what their text embeddings share, reaches the decoder (set_style_statistics)
        self.style_standardize = style_standardize if style_dim else None
        if self.style_standardize is not None:
            self.register_buffer("style_mean", torch.zeros(style_dim))
            self.register_buffer("style_scale", torch.tensor(1.0))
        self.music_encoder = nn.Sequential(
            *(
                EncoderLayer(d_model, n_heads, ff_dim, dropout, rotary_placement=rotary_placement)
                for _ in range(music_encoder_layers)
            )
        )
        self.music_pool = nn.Sequential(
            nn.LayerNorm(d_model), nn.Linear(d_model, d_model), nn.SiLU(), nn.Linear(d_model, d_model)
        )
        self.memory_norm = nn.LayerNorm(d_model)
        # frame-aligned music: each frame's encoded music token, projected, is added to that frame's motion token;
        # zero-initialised, so training starts from the cross-attention-only denoiser
        self.aligned_proj: nn.Linear | None = None
        if aligned_music:
            self.aligned_proj = nn.Linear(d_model, d_model)
            nn.init.zeros_(self.aligned_proj.weight)
            nn.init.zeros_(self.aligned_proj.bias)

        self.layers = nn.ModuleList(
            DecoderLayer(
                d_model,
                n_heads,
                ff_dim,
                dropout,
                rotary_placement=rotary_placement,
                cross_attention_rotary=cross_attention_rotary,
            )
            for _ in range(n_layers)
        )
        self.modulations: nn.ModuleList | None = None
        if self.use_modulation:
            count = 1 if modulation_shared else n_layers
            self.modulations = nn.ModuleList(
                StyleModulation(d_model, style_in, variant=modulation_variant) for _ in range(count)
            )
        self.output_proj = nn.Linear(d_model, pose_dim)

    def _run(self, layer: nn.Module, *args: torch.Tensor | nn.Module | None) -> torch.Tensor:
        """``layer(*args)``, recomputing its activations in the backward pass when gradient checkpointing is on."""
        if self.gradient_checkpointing and self.training and torch.is_grad_enabled():
            return checkpoint(layer, *args, use_reentrant=False)
        return layer(*args)

    def style_parameters(self) -> list[nn.Parameter]:
        """The parameters of the style's ways in: Style Modulation's projections, the null style and the style's
        FiLM and concatenation projections (``optimizer.style_lr_scale`` trains them at their own rate)."""
        parts: list[nn.Module | nn.Parameter | None] = [self.modulations, self.null_style, self.style_film_proj,
                                                        self.style_concat_proj]  # fmt: skip
        out: list[nn.Parameter] = []
        for part in parts:
            if isinstance(part, nn.Parameter):
                out.append(part)
            elif part is not None:
                out.extend(part.parameters())
        return out

    def set_style_statistics(self, vectors: torch.Tensor) -> None:
        """Centre and scale style vectors by these (the training style bank, (N, ds)) from now on; a no-op unless
        the model was built with ``style_standardize``. The statistics are buffers: checkpoints keep them."""
        if self.style_standardize is None:
            return
        if vectors.ndim != 2 or vectors.shape[-1] != self.style_dim or len(vectors) < 2:
            raise ValueError(f"style statistics need (N >= 2, {self.style_dim}) vectors, got {tuple(vectors.shape)}")
        vectors = vectors.to(self.style_mean)
        mean = vectors.mean(0)
        rms = (vectors - mean).pow(2).mean().sqrt()
        if not torch.isfinite(rms) or rms <= 0:
            raise ValueError("the style bank's vectors are all equal (or not finite): nothing to standardise by")
        self.style_mean.copy_(mean)
        self.style_scale.fill_(self.style_standardize / float(rms))

    def _style(self, style: torch.Tensor | None, keep: torch.Tensor, batch: int) -> torch.Tensor | None:
        if not self.style_dim:
            return None
        null = self.null_style.expand(batch, self.style_in)
        if style is not None and style.shape[-1] != self.style_in:
            extra = self.movement_channels
            plural = "s" if len(extra) > 1 else ""
            what = (
                f"{self.style_dim} style channels and the {', '.join(extra)} channel{plural}" if extra else "its style"
            )
            raise ValueError(
                f"this denoiser takes style vectors of {self.style_in} channels ({what}), got {tuple(style.shape)}"
            )
        if style is None:
            return null
        if self.style_standardize is not None:  # the text embedding's channels only, not the movement channels
            text = (style[..., : self.style_dim] - self.style_mean.to(style.dtype)) * self.style_scale.to(style.dtype)
            style = torch.cat((text, style[..., self.style_dim :]), dim=-1)
        if style.ndim == 3:  # per-frame style (B, T, ds)
            return torch.where(keep[:, None, None], style, null[:, None, :])
        return torch.where(keep[:, None], style, null)

    def _keep(self, keep: torch.Tensor | None, b: int, device: torch.device) -> torch.Tensor:
        return torch.ones(b, dtype=torch.bool, device=device) if keep is None else keep

    def _music(
        self,
        music: torch.Tensor | None,
        style: torch.Tensor | None,
        keep_music: torch.Tensor,
        keep_style: torch.Tensor,
        n: int,
        *,
        project_kept_only: bool = False,
        music_rows: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Music tokens (B, n, d), the pooled music vector (B, d) and the style after dropout.
        ``project_kept_only`` (nulls at the encoder's input): run ``music_proj`` on the rows whose music is kept
        only (one host sync to find them; for once-per-run conditioning). With the nulls after the encoder the
        dropped rows skip the whole music path (:meth:`_music_kept_rows`)."""
        b = keep_music.shape[0]
        null = self.null_music[:, :n].expand(b, -1, -1)
        if music is None or self.music_proj is None:
            music, keep_music = None, torch.zeros_like(keep_music)
        elif (music.shape[0] if music_rows is None else music_rows.shape[0], music.shape[1]) != (b, n) or (
            music.shape[-1] != self.audio_dim
        ):
            raise ValueError(f"music features {tuple(music.shape)} do not match ({b}, {n}, {self.audio_dim})")
        if self.null_music_at == "output":
            return self._music_kept_rows(music, style, keep_music, keep_style, null, music_rows)
        if music is None:
            h_music = null
        elif project_kept_only:
            rows = keep_music.nonzero().squeeze(1)
            projected = self.music_proj(_rows_of(music, rows, music_rows))
            h_music = null.to(projected.dtype).clone(memory_format=torch.contiguous_format)
            h_music.index_copy_(0, rows, projected)
        else:
            h_music = torch.where(keep_music[:, None, None], self.music_proj(music), null)
        s = self._style(style, keep_style, b)
        tokens = self._run(self.music_encoder, self._with_style(h_music, s))
        return tokens, self.music_pool(tokens.mean(dim=1)), s

    def _with_style(self, h_music: torch.Tensor, s: torch.Tensor | None) -> torch.Tensor:
        """The music tokens with the projected style added (concat injection), else as they are."""
        if self.style_concat_proj is None:
            return h_music
        h_style = self.style_concat_proj(s)
        return h_music + (h_style if h_style.ndim == 3 else h_style[:, None, :])

    def _music_kept_rows(
        self,
        music: torch.Tensor | None,
        style: torch.Tensor | None,
        keep_music: torch.Tensor,
        keep_style: torch.Tensor,
        null: torch.Tensor,
        music_rows: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """:meth:`_music` with the null tokens after the encoder (EDGE): the encoder and the pooling run on the rows
        whose music is kept only (the other rows' results would be replaced by the nulls; one host sync to find
        them), which saves a quarter of the music path in training at EDGE's condition dropout of 0.25."""
        b = keep_music.shape[0]
        s = self._style(style, keep_style, b)
        rows = keep_music.nonzero().squeeze(1)
        if music is None or rows.numel() == 0:
            return null, self.null_music_hidden.expand(b, -1), s
        h_music = self.music_proj(_rows_of(music, rows, music_rows))
        kept = self._run(self.music_encoder, self._with_style(h_music, None if s is None else s[rows]))
        pooled_kept = self.music_pool(kept.mean(dim=1))
        tokens = null.to(kept.dtype).clone(memory_format=torch.contiguous_format)
        pooled = self.null_music_hidden.expand(b, -1).to(pooled_kept.dtype).clone(memory_format=torch.contiguous_format)
        return tokens.index_copy_(0, rows, kept), pooled.index_copy_(0, rows, pooled_kept), s

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
        music_rows: torch.Tensor | None = None,
    ) -> DenoiserCondition:
        """The conditioning of ``forward(x_t, t, cond=...)`` for music (B, T, Da) and style, computed once for a
        whole sampling run: music encoder, pooled music, style, and the cross-attention keys and values of the
        music tokens. The rows' batch and length come from the music (or from ``batch`` / ``n_frames``).
        ``music_rows`` (B,): row i hears ``music[music_rows[i]]`` (a run's music repeated over the guidance
        passes without a copy of it; for a 5-minute song at 4800-d that copy was 0.7 GB)."""
        if music is not None:
            batch, n_frames = music.shape[0] if music_rows is None else music_rows.shape[0], music.shape[1]
        if batch is None:
            batch = keep_music.shape[0] if keep_music is not None else style.shape[0] if style is not None else None
        if batch is None or n_frames is None:
            raise ValueError("condition() needs the batch size and the number of frames when there is no music")
        if n_frames > self.seq_len:
            raise ValueError(f"sequence of {n_frames} frames is longer than the model's {self.seq_len}; use long-form")
        device = self.null_music.device
        keep_music = self._keep(keep_music, batch, device)
        keep_style = self._keep(keep_style, batch, device)
        tokens, pooled, s = self._music(
            music, style, keep_music, keep_style, n_frames, project_kept_only=True, music_rows=music_rows
        )
        memory = self.memory_norm(tokens)  # LayerNorm is per token: the time tokens are normalised per step
        aligned = self._aligned(memory)
        shared = self._shared_null_rows(keep_music, s)
        if shared:  # one copy of the null music's keys and values for the leading rows that share it
            memory = torch.cat((memory[:1], memory[shared:]))
        keys, values = [], []
        for layer in self.layers:
            k, v = layer.cross_attn.keys_values(memory)
            shape = (*k.shape[:2], n_frames + 2, k.shape[-1])
            k_all, v_all = k.new_empty(shape), v.new_empty(shape)
            k_all[:, :, :n_frames], v_all[:, :, :n_frames] = k, v
            keys.append(k_all)
            values.append(v_all)
        return DenoiserCondition(s, pooled, keys, values, n_frames, aligned=aligned, shared_rows=shared)

    def _shared_null_rows(self, keep_music: torch.Tensor, style: torch.Tensor | None) -> int:
        """How many leading rows have dropped music and therefore the same memory (0 if fewer than 2): the null
        music sequence, through the music encoder unless the nulls replace its output; with a style concatenated
        before the encoder, the rows' styles must be the same too (one style for a whole song, as generation
        gives it)."""
        kept = keep_music.nonzero()
        leading = int(kept[0, 0]) if kept.numel() else keep_music.shape[0]
        if leading < 2:
            return 0
        if self.use_concat and self.null_music_at == "input" and style is not None:
            if not bool((style[:leading] == style[:1]).all()):
                return 0
        return leading

    def _aligned(self, memory: torch.Tensor) -> torch.Tensor | None:
        """The frame-aligned music (B, T, d) from the normalised music tokens, or None when it is off."""
        return None if self.aligned_proj is None else self.aligned_proj(memory)

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
        guidance: torch.Tensor | None = None,
        same_step: bool = False,
    ) -> torch.Tensor:
        """x_t (B, T, pose_dim), t (B,), music (B, T, Da), style (B, ds) or (B, T, ds); keep_* (B,) bool
        (False = condition dropped); or, instead of music, style and keep_*, ``cond`` from :meth:`condition`
        (sampling). ``guidance`` (B, guidance_inputs): the guidance weights of a guidance-distilled student
        (music, then style). ``same_step`` (with ``cond``): the caller knows that every row is at the same
        diffusion step with the same guidance weights, as at each step of a sampler, so the rows that share the
        null music's keys and values share their time tokens too without a comparison read back from the device.
        Returns x0 prediction (B, T, pose_dim)."""
        b, n, _ = x_t.shape
        if n > self.seq_len:
            raise ValueError(f"sequence of {n} frames is longer than the model's {self.seq_len}; use long-form")
        t_hidden = self.time_mlp(self._step_embedding(t, guidance))
        t_cond = self.time_film(t_hidden)
        t_tokens = self.time_tokens(t_hidden).view(b, 2, self.d_model)
        if cond is not None:
            return self._forward_cached(x_t, t_cond, t_tokens, cond, same_step)

        keep_music = self._keep(keep_music, b, x_t.device)
        keep_style = self._keep(keep_style, b, x_t.device)
        tokens, pooled, s = self._music(music, style, keep_music, keep_style, n)
        t_cond = self._with_style_film(t_cond + pooled, s)
        memory = self.memory_norm(torch.cat((tokens, t_tokens), dim=1))

        h = self._input(x_t)
        aligned = self._aligned(memory[:, :n])
        if aligned is not None:
            h = h + aligned
        for i, layer in enumerate(self.layers):
            h = self._run(layer, h, memory, t_cond, s, self._modulation(i))
        return self._output(h)

    def _step_embedding(self, t: torch.Tensor, guidance: torch.Tensor | None) -> torch.Tensor:
        """The sinusoidal embedding of the diffusion step, plus that of the guidance weights for a student."""
        emb = sinusoidal_embedding(t, self.d_model)
        if self.guidance_proj is None:
            if guidance is not None:
                raise ValueError("guidance weights were given to a denoiser that takes none (guidance_inputs=0)")
            return emb
        if guidance is None or guidance.shape != (t.shape[0], self.guidance_inputs):
            got = None if guidance is None else tuple(guidance.shape)
            raise ValueError(f"this guidance-distilled denoiser needs guidance weights ({t.shape[0]}, "
                             f"{self.guidance_inputs}), got {got}")  # fmt: skip
        features = torch.cat([sinusoidal_embedding(w * GUIDANCE_SCALE, self.d_model) for w in guidance.unbind(1)], 1)
        return emb + self.guidance_proj(features)

    def _input(self, x_t: torch.Tensor) -> torch.Tensor:
        """The motion tokens of x_t, projected in float32 even under bf16 autocast (see :meth:`_output`)."""
        with torch.autocast(x_t.device.type, enabled=False):
            return self.input_proj(x_t.float())

    def _output(self, h: torch.Tensor) -> torch.Tensor:
        """The x0 prediction from the last hidden state, in float32 even under bf16 autocast: bf16 keeps 8 bits of
        mantissa, and rounding each frame's pose to them on its own shook the motion (a few millimetres per frame,
        a visible jitter that the music guidance then amplifies)."""
        with torch.autocast(h.device.type, enabled=False):
            return self.output_proj(h.float())

    def _with_style_film(self, t_cond: torch.Tensor, s: torch.Tensor | None) -> torch.Tensor:
        """The FiLM condition (B, d), plus the projected style with ``style_film``: (B, d), or (B, T, d) for a style
        per frame (a schedule)."""
        if self.style_film_proj is None or s is None:
            return t_cond
        h_style = self.style_film_proj(s.to(t_cond.dtype))
        return t_cond + h_style if h_style.ndim == 2 else t_cond[:, None, :] + h_style

    def _modulation(self, i: int) -> StyleModulation | None:
        return None if self.modulations is None else self.modulations[min(i, len(self.modulations) - 1)]

    def _forward_cached(
        self,
        x_t: torch.Tensor,
        t_cond: torch.Tensor,
        t_tokens: torch.Tensor,
        cond: DenoiserCondition,
        same_step: bool = False,
    ) -> torch.Tensor:
        b, n, _ = x_t.shape
        if (cond.batch_size, cond.n_frames) != (b, n):
            raise ValueError(
                f"the conditioning is for {cond.batch_size} rows of {cond.n_frames} frames, not ({b}, {n})"
            )
        t_cond = self._with_style_film(t_cond + cond.pooled, cond.style)
        t_memory = self.memory_norm(t_tokens)
        h = self._input(x_t)
        if cond.aligned is not None:
            h = h + cond.aligned
        shared = cond.shared_rows
        # the shared rows' time tokens are written once when those rows are at the same step (sampling); otherwise
        # this call works on a full copy of their keys and values. A sampler says so (same_step): only other callers
        # pay for the comparison, which waits for the device to read its result back.
        expand = bool(shared) and not same_step and not bool((t_memory[:shared] == t_memory[:1]).all())
        if shared and not expand:
            t_memory = torch.cat((t_memory[:1], t_memory[shared:]))
        for i, layer in enumerate(self.layers):
            keys, values = cond.keys[i], cond.values[i]
            if expand:
                keys, values = (torch.cat((kv[:1].expand(shared, -1, -1, -1), kv[1:])) for kv in (keys, values))
            # the time tokens' keys and values go into the last two positions of the cached memory
            keys[:, :, n:], values[:, :, n:] = layer.cross_attn.keys_values(t_memory, start=n)
            h = layer(h, None, t_cond, cond.style, self._modulation(i), memory_kv=(keys, values),
                      shared_rows=0 if expand else shared)  # fmt: skip
        return self._output(h)
