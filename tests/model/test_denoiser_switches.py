"""Denoiser switches: EDGE's architecture (parameter count derived by hand, rotary on the attention inputs,
cross-attention rotary, null music after the encoder) and activation checkpointing."""

import math

import pytest
import torch
import torch.nn.functional as F

from dgsdp.cli.config import compose_config
from dgsdp.cli.train import audio_encoder_from_config, style_embedder_from_config
from dgsdp.model import DanceDenoiser
from dgsdp.model.layers import Attention
from dgsdp.trained.spec import RunSpec
from dgsdp.training import DanceDiffusion

EDGE = {"rotary_placement": "input", "cross_attention_rotary": True, "null_music": "output"}


def edge_parameter_count(d=512, ff=1024, layers=8, audio=4800, pose=151, frames=150):
    """EDGE's DanceDecoder counted layer by layer from its definition (nn.MultiheadAttention: 4 d x d weights
    and 4 d biases; DenseFiLM: Mish -> Linear(d, 2d))."""

    def linear(i, o):
        return i * o + o

    attention, feed_forward, layer_norm, film = (
        4 * d * d + 4 * d,
        linear(d, ff) + linear(ff, d),
        2 * d,
        linear(d, 2 * d),
    )
    encoder_layer = attention + feed_forward + 2 * layer_norm
    decoder_layer = 2 * attention + feed_forward + 3 * layer_norm + 3 * film
    time = linear(d, 4 * d) + linear(4 * d, d) + linear(4 * d, 2 * d)
    nulls = frames * d + d  # null_cond_embed (1, 150, d), null_cond_hidden (1, d)
    music = linear(audio, d) + 2 * encoder_layer + layer_norm + 2 * linear(d, d)  # + non_attn_cond_projection
    return linear(pose, d) + time + nulls + music + layer_norm + layers * decoder_layer + linear(d, pose)


def test_edge_experiment_has_edges_parameter_count(tmp_path):
    assert edge_parameter_count() == 49_464_471  # "49.46M" in the README's table
    cfg = compose_config("train", ["experiment=edge"], output_dir=tmp_path)
    spec = RunSpec.from_config(
        cfg, audio_encoder=audio_encoder_from_config(cfg), style_embedder=style_embedder_from_config(cfg),
        style_bank_size=0, groups={},
    )  # fmt: skip
    assert {k: spec.model[k] for k in EDGE} == EDGE
    model = DanceDiffusion(spec)
    assert sum(p.numel() for p in model.denoiser.parameters()) == edge_parameter_count()
    # the default denoiser has no null pooled vector: exactly d = 512 parameters fewer
    default = DanceDenoiser(audio_dim=4800)
    assert sum(p.numel() for p in default.parameters()) == edge_parameter_count() - 512


def rotate_complex(x, base=10000.0):
    """RoPE written with complex numbers: channel pairs (2i, 2i+1) at position p turn by p / base^(2i / D)."""
    *_, t, dim = x.shape
    z = torch.view_as_complex(x.double().reshape(*x.shape[:-1], dim // 2, 2).contiguous())
    angle = torch.arange(t, dtype=torch.float64)[:, None] / base ** (torch.arange(0, dim, 2) / dim)[None]
    return torch.view_as_real(z * torch.polar(torch.ones_like(angle), angle)).reshape(x.shape).float()


def reference_attention(attn, x, memory, placement):
    """Multi-head attention computed from the layer's weights without its code path."""
    d, h = x.shape[-1], attn.n_heads
    w_k, w_v = attn.kv.weight[:d], attn.kv.weight[d:]
    b_k, b_v = attn.kv.bias[:d], attn.kv.bias[d:]

    def heads(a):
        return a.reshape(*a.shape[:2], h, d // h).transpose(1, 2)

    if placement == "input":
        q = heads(F.linear(rotate_complex(x), attn.q.weight, attn.q.bias))
        k = heads(F.linear(rotate_complex(memory), w_k, b_k))
    else:
        q = rotate_complex(heads(F.linear(x, attn.q.weight, attn.q.bias)))
        k = rotate_complex(heads(F.linear(memory, w_k, b_k)))
    v = heads(F.linear(memory, w_v, b_v))
    weights = torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(d // h), dim=-1)
    return attn.out((weights @ v).transpose(1, 2).reshape(*x.shape))


@pytest.mark.parametrize("placement", ["input", "qk"])
@pytest.mark.parametrize("cross", [False, True])
def test_rotary_attention_matches_reference(placement, cross):
    torch.manual_seed(0)
    attn = Attention(32, 4, dropout=0.0, rotary=True, rotary_placement=placement).eval()
    x = torch.randn(2, 10, 32)
    memory = torch.randn(2, 12, 32) if cross else None
    expected = reference_attention(attn, x, x if memory is None else memory, placement)
    assert torch.allclose(attn(x, memory), expected, atol=1e-5)


def test_edge_and_default_rotate_cross_attention_and_differ_in_placement():
    edge = DanceDenoiser(d_model=32, n_layers=1, n_heads=2, ff_dim=64, audio_dim=8, **EDGE)
    default = DanceDenoiser(d_model=32, n_layers=1, n_heads=2, ff_dim=64, audio_dim=8)
    assert edge.layers[0].cross_attn.rotary is not None and default.layers[0].cross_attn.rotary is not None
    assert edge.layers[0].self_attn.rotary_placement == "input" and default.layers[0].self_attn.rotary_placement == "qk"
    switched_off = DanceDenoiser(
        d_model=32, n_layers=1, n_heads=2, ff_dim=64, audio_dim=8, cross_attention_rotary=False
    )
    assert switched_off.layers[0].cross_attn.rotary is None


@pytest.mark.parametrize("null_music", ["input", "output"])
def test_dropped_music_ignores_the_music(null_music):
    torch.manual_seed(0)
    model = DanceDenoiser(d_model=32, n_layers=1, n_heads=2, ff_dim=64, audio_dim=8, null_music=null_music).eval()
    x, t = torch.randn(3, 20, 151), torch.tensor([3, 500, 900])
    keep = torch.tensor([True, False, True])
    a, b = model(x, t, torch.randn(3, 20, 8), keep_music=keep), model(x, t, torch.randn(3, 20, 8), keep_music=keep)
    assert torch.allclose(a[1], b[1], atol=1e-6) and not torch.allclose(a[0], b[0])
    assert torch.allclose(a[1], model(x, t, None)[1], atol=1e-6)  # dropped = no music at all
    if null_music == "output":  # the null pooled vector conditions exactly the dropped rows
        with torch.no_grad():
            model.null_music_hidden.add_(1.0)
        c = model(x, t, torch.randn(3, 20, 8), keep_music=keep)
        assert not torch.allclose(a[1], c[1]) and model.null_music_hidden.numel() == 32


@pytest.mark.parametrize("null_music", ["input", "output"])
def test_rows_of_a_mixed_batch_match_the_rows_alone(null_music):
    """Kept and dropped rows together give each row's result alone (with the nulls after the encoder only the
    kept rows run the music path), and the nulls and the music projection both get their gradients."""
    torch.manual_seed(0)
    model = DanceDenoiser(d_model=32, n_layers=1, n_heads=2, ff_dim=64, audio_dim=8, null_music=null_music).eval()
    x, t, music = torch.randn(4, 20, 151), torch.tensor([3, 500, 900, 40]), torch.randn(4, 20, 8)
    keep = torch.tensor([True, False, False, True])
    together = model(x, t, music, keep_music=keep)
    for i in range(4):
        alone = model(x[i : i + 1], t[i : i + 1], music[i : i + 1], keep_music=keep[i : i + 1])
        assert torch.allclose(together[i], alone[0], atol=1e-5)
    together.square().sum().backward()
    assert model.null_music.grad.abs().sum() > 0 and model.music_proj.weight.grad.abs().sum() > 0
    if null_music == "output":
        assert model.null_music_hidden.grad.abs().sum() > 0


def test_gradient_checkpointing_gives_the_same_loss_and_gradients():
    torch.manual_seed(0)
    model = DanceDenoiser(d_model=32, n_layers=2, n_heads=2, ff_dim=64, audio_dim=8, dropout=0.1).train()
    x, t, music = torch.randn(2, 20, 151), torch.tensor([3, 700]), torch.randn(2, 20, 8)
    results = []
    for checkpointing in (False, True):
        model.gradient_checkpointing = checkpointing
        model.zero_grad()
        torch.manual_seed(1)  # same dropout masks (checkpointing replays the RNG state in the backward pass)
        out = model(x, t, music)
        out.square().mean().backward()
        results.append((out.detach(), [p.grad.clone() for p in model.parameters()]))
    assert torch.equal(results[0][0], results[1][0])
    assert all(torch.allclose(a, b, atol=1e-7) for a, b in zip(results[0][1], results[1][1], strict=True))


def test_runs_stored_without_the_cross_attention_switch_load_without_positions():
    """A checkpoint from before ``cross_attention_rotary`` existed was trained without rotary cross-attention: it
    loads that way (the constructor's default is for new runs), a stored value wins, and resuming such a run with
    today's config is refused as a different architecture."""
    import dataclasses

    spec = RunSpec.from_groups(
        model="small", audio_dim=8, style_dim=0, style_kind="none", style_bank_size=0, n_genres=10,
        d_model=32, n_layers=1, n_heads=2, ff_dim=64, music_encoder_layers=1, dropout=0.0,
    )  # fmt: skip
    assert spec.build_denoiser("config").layers[0].cross_attn.rotary is not None
    old = dataclasses.replace(spec, model={k: v for k, v in spec.model.items() if k != "cross_attention_rotary"})
    assert old.build_denoiser("checkpoint").layers[0].cross_attn.rotary is None
    assert old.build_denoiser("config").layers[0].cross_attn.rotary is not None  # a config gets the default
    stored = dataclasses.replace(spec, model={**old.model, "cross_attention_rotary": True})
    assert stored.build_denoiser("checkpoint").layers[0].cross_attn.rotary is not None
    assert old.architecture()["model"]["cross_attention_rotary"] is False
    assert spec.architecture()["model"]["cross_attention_rotary"] is True


def test_bf16_autocast_keeps_the_motion_projections_in_float32():
    """Under bf16 autocast the x0 prediction is not rounded to bf16 (that rounding shook the dances; see
    DanceDenoiser._output), in the per-step and in the cached-conditioning path, and stays near float32's."""
    torch.manual_seed(0)
    model = DanceDenoiser(d_model=32, n_layers=2, n_heads=2, ff_dim=64, audio_dim=8).eval()
    x, t, music = torch.randn(2, 20, 151), torch.tensor([3, 700]), torch.randn(2, 20, 8)
    reference = model(x, t, music)
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        per_step = model(x, t, music)
        cached = model(x, t, cond=model.condition(music, None))
    for out in (per_step, cached):
        assert out.dtype == torch.float32
        assert not torch.equal(out, out.bfloat16().float())
        assert (out - reference).abs().max() < 0.1 * reference.abs().max()
