"""EDGE's ``DanceDecoder`` weights in :class:`dgsdp.model.DanceDenoiser`'s names.

The denoiser with ``rotary_placement="input", null_music="output"`` (``experiment=edge``) is EDGE's architecture
with the same parameters under other names; only the attention layers are packed differently: EDGE's
``nn.MultiheadAttention`` keeps the query, key and value projections in one ``in_proj_weight`` (3d, d), ours a query
projection (d, d) and a key-value projection (2d, d). The sizes are read from the weights; the number of heads is
not in them (EDGE's code fixes 8).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import torch

from dgsdp.errors import CheckpointError

EDGE_HEADS = 8  # EDGE.py builds DanceDecoder(num_heads=8)
EDGE_POSE_DIM = 151
# EDGE's two feature types by the input width of ``cond_projection`` (EDGE.py: feature_dim = 35 if baseline else 4800)
FEATURE_TYPES = {35: "baseline", 4800: "jukebox"}
ROTARY_BASE = 10000.0

# EDGE name -> ours, for the parts outside the layer stacks
_TOP = {
    "null_cond_embed": "null_music",
    "null_cond_hidden": "null_music_hidden",
    "input_projection": "input_proj",
    "time_mlp.1": "time_mlp.0",
    "to_time_cond.0": "time_film",
    "to_time_tokens.0": "time_tokens",
    "cond_projection": "music_proj",
    "non_attn_cond_projection.0": "music_pool.0",
    "non_attn_cond_projection.1": "music_pool.1",
    "non_attn_cond_projection.3": "music_pool.3",
    "norm_cond": "memory_norm",
    "final_layer": "output_proj",
}
# within one layer: EDGE name -> ours (attention blocks are handled apart)
_ENCODER_LAYER = {"norm1": "norm1", "norm2": "norm2", "linear1": "ff.0", "linear2": "ff.3"}
_DECODER_LAYER = {
    "norm1": "norm1", "norm2": "norm2", "norm3": "norm3", "linear1": "ff.0", "linear2": "ff.3",
    "film1.block.1": "film1.proj.1", "film2.block.1": "film2.proj.1", "film3.block.1": "film3.proj.1",
}  # fmt: skip
_ATTENTION = {"self_attn": "self_attn", "multihead_attn": "cross_attn"}


@dataclass(frozen=True)
class EdgeArchitecture:
    """The sizes of an EDGE DanceDecoder, read from its weights."""

    d_model: int
    n_layers: int
    ff_dim: int
    seq_len: int
    feature_dim: int
    encoder_layers: int

    @property
    def feature_type(self) -> str:
        return FEATURE_TYPES[self.feature_dim]

    def expected_shapes(self) -> dict[str, tuple[int, ...]]:
        """Every tensor of EDGE's DanceDecoder state dict at these sizes (rotary frequency buffers included)."""
        d, ff = self.d_model, self.ff_dim
        shapes: dict[str, tuple[int, ...]] = {
            "rotary.freqs": (d // 2,),
            "null_cond_embed": (1, self.seq_len, d),
            "null_cond_hidden": (1, d),
            "input_projection.weight": (d, EDGE_POSE_DIM),
            "input_projection.bias": (d,),
            "time_mlp.1.weight": (4 * d, d),
            "time_mlp.1.bias": (4 * d,),
            "to_time_cond.0.weight": (d, 4 * d),
            "to_time_cond.0.bias": (d,),
            "to_time_tokens.0.weight": (2 * d, 4 * d),
            "to_time_tokens.0.bias": (2 * d,),
            "cond_projection.weight": (d, self.feature_dim),
            "cond_projection.bias": (d,),
            "non_attn_cond_projection.0.weight": (d,),
            "non_attn_cond_projection.0.bias": (d,),
            "non_attn_cond_projection.1.weight": (d, d),
            "non_attn_cond_projection.1.bias": (d,),
            "non_attn_cond_projection.3.weight": (d, d),
            "non_attn_cond_projection.3.bias": (d,),
            "norm_cond.weight": (d,),
            "norm_cond.bias": (d,),
            "final_layer.weight": (EDGE_POSE_DIM, d),
            "final_layer.bias": (EDGE_POSE_DIM,),
        }

        def attention(prefix: str) -> None:
            shapes.update({
                f"{prefix}.in_proj_weight": (3 * d, d), f"{prefix}.in_proj_bias": (3 * d,),
                f"{prefix}.out_proj.weight": (d, d), f"{prefix}.out_proj.bias": (d,),
            })  # fmt: skip

        def common(prefix: str, norms: int) -> None:
            shapes.update({f"{prefix}.rotary.freqs": (d // 2,), f"{prefix}.linear1.weight": (ff, d)})
            shapes.update({f"{prefix}.linear1.bias": (ff,), f"{prefix}.linear2.weight": (d, ff)})
            shapes[f"{prefix}.linear2.bias"] = (d,)
            for k in range(1, norms + 1):
                shapes[f"{prefix}.norm{k}.weight"] = shapes[f"{prefix}.norm{k}.bias"] = (d,)

        for i in range(self.encoder_layers):
            common(f"cond_encoder.{i}", 2)
            attention(f"cond_encoder.{i}.self_attn")
        for i in range(self.n_layers):
            prefix = f"seqTransDecoder.stack.{i}"
            common(prefix, 3)
            attention(f"{prefix}.self_attn")
            attention(f"{prefix}.multihead_attn")
            for k in (1, 2, 3):
                shapes[f"{prefix}.film{k}.block.1.weight"] = (2 * d, d)
                shapes[f"{prefix}.film{k}.block.1.bias"] = (2 * d,)
        return shapes


def _shape(state: dict[str, torch.Tensor], key: str, ndim: int) -> tuple[int, ...]:
    if key not in state:
        raise CheckpointError(f"the weights have no {key}; they are not EDGE's DanceDecoder")
    shape = tuple(state[key].shape)
    if len(shape) != ndim:
        raise CheckpointError(f"{key} has shape {shape}; EDGE's DanceDecoder has a {ndim}-d tensor there")
    return shape


def _count(state: dict[str, torch.Tensor], pattern: str) -> int:
    found = {int(m.group(1)) for k in state if (m := re.match(pattern, k))}
    if found != set(range(len(found))):
        raise CheckpointError(f"the weights' layers {sorted(found)} are not numbered 0..{len(found) - 1}")
    return len(found)


def edge_architecture(state: dict[str, torch.Tensor]) -> EdgeArchitecture:
    """The sizes of the DanceDecoder whose weights are ``state``; a CheckpointError when they match no EDGE
    configuration (151-d poses, 35-d or 4800-d music features, consistent layer shapes, no missing or extra keys)."""
    d, pose_dim = _shape(state, "input_projection.weight", 2)
    if pose_dim != EDGE_POSE_DIM:
        raise CheckpointError(f"the model reads {pose_dim}-d poses; EDGE's read {EDGE_POSE_DIM}-d pose vectors")
    _, feature_dim = _shape(state, "cond_projection.weight", 2)
    if feature_dim not in FEATURE_TYPES:
        raise CheckpointError(
            f"the model reads {feature_dim}-d music features; EDGE's read 35-d (baseline) or 4800-d (Jukebox) ones"
        )
    _, seq_len, _ = _shape(state, "null_cond_embed", 3)
    ff_dim = _shape(state, "seqTransDecoder.stack.0.linear1.weight", 2)[0]
    arch = EdgeArchitecture(
        d_model=d,
        n_layers=_count(state, r"seqTransDecoder\.stack\.(\d+)\."),
        ff_dim=ff_dim,
        seq_len=seq_len,
        feature_dim=feature_dim,
        encoder_layers=_count(state, r"cond_encoder\.(\d+)\."),
    )
    if d % (2 * EDGE_HEADS):
        raise CheckpointError(
            f"width {d} is not a multiple of {2 * EDGE_HEADS} (EDGE's {EDGE_HEADS} heads, rotary pairs)"
        )
    expected = arch.expected_shapes()
    missing = sorted(set(expected) - set(state))
    extra = sorted(set(state) - set(expected))
    wrong = [f"{k} {tuple(state[k].shape)} (expected {expected[k]})" for k in expected if k in state and tuple(state[k].shape) != expected[k]]  # fmt: skip
    if missing or extra or wrong:
        parts = [
            f"missing: {', '.join(missing[:8])}" if missing else "",
            f"unexpected: {', '.join(extra[:8])}" if extra else "",
        ]
        parts.append(f"wrong shapes: {', '.join(wrong[:8])}" if wrong else "")
        raise CheckpointError(
            f"the weights do not match EDGE's DanceDecoder ({'; '.join(p for p in parts if p)})"
        )  # fmt: skip
    return arch


def _check_rotary(state: dict[str, torch.Tensor], arch: EdgeArchitecture) -> None:
    """EDGE's rotary frequencies are the standard ones (base 10000 over the full width), which the denoiser uses."""
    d = arch.d_model
    standard = 1.0 / ROTARY_BASE ** (torch.arange(0, d, 2).float() / d)
    for key, value in state.items():
        if key.endswith("rotary.freqs") and not torch.allclose(value.float(), standard, rtol=1e-5, atol=0):
            raise CheckpointError(f"{key} are not the standard rotary frequencies; this is not EDGE's rotary embedding")


def to_dgsdp(state: dict[str, torch.Tensor], arch: EdgeArchitecture | None = None) -> dict[str, torch.Tensor]:
    """EDGE DanceDecoder weights -> a :class:`~dgsdp.model.DanceDenoiser` state dict (``experiment=edge``)."""
    arch = arch or edge_architecture(state)
    _check_rotary(state, arch)
    d = arch.d_model
    out: dict[str, torch.Tensor] = {}
    for edge_key, value in state.items():
        if edge_key.endswith("rotary.freqs"):
            continue  # computed, not learned
        if (m := re.match(r"(cond_encoder)\.(\d+)\.(.+)$", edge_key)) is not None:
            prefix, rest, table = f"music_encoder.{m.group(2)}", m.group(3), _ENCODER_LAYER
        elif (m := re.match(r"(seqTransDecoder\.stack)\.(\d+)\.(.+)$", edge_key)) is not None:
            prefix, rest, table = f"layers.{m.group(2)}", m.group(3), _DECODER_LAYER
        else:
            name, _, param = edge_key.rpartition(".")
            if edge_key in _TOP:
                out[_TOP[edge_key]] = value
            else:
                out[f"{_TOP[name]}.{param}"] = value
            continue
        attn, _, param = rest.partition(".")
        if attn in _ATTENTION:
            ours = "attn" if prefix.startswith("music_encoder") else _ATTENTION[attn]
            if param == "in_proj_weight":
                out[f"{prefix}.{ours}.q.weight"], out[f"{prefix}.{ours}.kv.weight"] = value[:d], value[d:]
            elif param == "in_proj_bias":
                out[f"{prefix}.{ours}.q.bias"], out[f"{prefix}.{ours}.kv.bias"] = value[:d], value[d:]
            else:  # out_proj.weight / out_proj.bias
                out[f"{prefix}.{ours}.out.{param.split('.')[-1]}"] = value
            continue
        name, _, param = rest.rpartition(".")
        out[f"{prefix}.{table[name]}.{param}"] = value
    return {k: v.detach().float().clone() for k, v in out.items()}
