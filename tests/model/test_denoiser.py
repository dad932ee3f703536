"""DanceDenoiser: shapes, dropped conditions (learned nulls), style injection variants, row independence, windows."""

import pytest
import torch
from model_helpers import AUDIO_DIM, POSE_DIM, SEQ_LEN, STYLE_DIM, inputs, tiny_denoiser

from dgsdp.model import DanceDenoiser

CLOSE = {"rtol": 1e-5, "atol": 1e-6}


def flags(*values: bool) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.bool)


@pytest.mark.parametrize(("audio_dim", "style_dim"), [(AUDIO_DIM, STYLE_DIM), (0, STYLE_DIM), (AUDIO_DIM, 0), (0, 0)])
@pytest.mark.parametrize(("b", "n"), [(1, SEQ_LEN), (3, 7), (2, 1)])
def test_output_shape(audio_dim, style_dim, b, n):
    model = tiny_denoiser(audio_dim, style_dim)
    x_t, t, music, style = inputs(b, n, audio_dim, style_dim)
    with torch.no_grad():
        out = model(x_t, t, music, style)
        assert out.shape == (b, n, POSE_DIM) and torch.isfinite(out).all()
        if style_dim:  # one style per frame
            _, _, _, frame_style = inputs(b, n, audio_dim, style_dim, per_frame=True)
            assert model(x_t, t, music, frame_style).shape == (b, n, POSE_DIM)


def test_sequence_and_music_shape_errors():
    model = tiny_denoiser()
    x_t, t, music, style = inputs(2, SEQ_LEN + 1)
    with pytest.raises(ValueError, match=f"longer than the model's {SEQ_LEN}"):
        model(x_t, t, music, style)
    x_t, t, music, style = inputs(2, 8)
    with pytest.raises(ValueError, match="music features"):
        model(x_t, t, music[:, :5], style)
    with pytest.raises(ValueError, match="music features"):
        model(x_t, t, torch.randn(2, 8, AUDIO_DIM + 1), style)
    with pytest.raises(ValueError, match="unknown style injection"):
        DanceDenoiser(style_dim=4, style_injection="add", d_model=16, n_heads=2)


@pytest.mark.parametrize("injection", ["modulation", "concat"])
def test_dropped_music_is_the_learned_null(injection):
    model = tiny_denoiser(style_injection=injection)
    x_t, t, music, style = inputs(4, 9)
    other_music = torch.randn_like(music)
    keep = flags(False, True, False, True)
    with torch.no_grad():
        a = model(x_t, t, music, style, keep_music=keep)
        b = model(x_t, t, other_music, style, keep_music=keep)
        none = model(x_t, t, None, style)
        # dropped rows do not depend on the music and equal the output without music; kept rows do depend on it
        torch.testing.assert_close(a[~keep], b[~keep], **CLOSE)
        torch.testing.assert_close(a[~keep], none[~keep], **CLOSE)
        assert (a[keep] - b[keep]).abs().amax() > 1e-3
        # the null is the learned parameter: changing it changes the dropped rows only
        model.null_music.add_(torch.randn_like(model.null_music))
        c = model(x_t, t, music, style, keep_music=keep)
    assert (c[~keep] - a[~keep]).abs().amax() > 1e-3
    torch.testing.assert_close(c[keep], a[keep], **CLOSE)


@pytest.mark.parametrize("per_frame", [False, True])
@pytest.mark.parametrize(
    "options",
    [
        {},
        {"style_injection": "concat"},
        {"also_concat": True},
        {"modulation_shared": False, "modulation_variant": "paper"},
    ],
    ids=["modulation", "concat", "modulation+concat", "per-layer-paper"],
)
def test_dropped_style_is_the_learned_null(options, per_frame):
    model = tiny_denoiser(**options)
    x_t, t, music, style = inputs(4, 9, per_frame=per_frame)
    other_style = torch.randn_like(style)
    keep = flags(True, False, False, True)
    null = model.null_style.detach()
    null_input = null.expand_as(style)
    with torch.no_grad():
        a = model(x_t, t, music, style, keep_style=keep)
        b = model(x_t, t, music, other_style, keep_style=keep)
        none = model(x_t, t, music, None)
        as_input = model(x_t, t, music, null_input)  # the null vector given as an ordinary style
        zero = model(x_t, t, music, torch.zeros_like(style))
    torch.testing.assert_close(a[~keep], b[~keep], **CLOSE)
    torch.testing.assert_close(a[~keep], none[~keep], **CLOSE)
    torch.testing.assert_close(a[~keep], as_input[~keep], **CLOSE)
    assert (a[keep] - b[keep]).abs().amax() > 1e-3
    assert (a[~keep] - zero[~keep]).abs().amax() > 1e-3  # the null is not a zero style


def test_model_without_music_or_style_ignores_them():
    model = tiny_denoiser(audio_dim=0, style_dim=0)
    x_t, t, _, _ = inputs(3, 6, audio_dim=0, style_dim=0)
    with torch.no_grad():
        a = model(x_t, t)
        b = model(x_t, t, None, None, keep_music=flags(False, True, False), keep_style=flags(True, False, False))
    torch.testing.assert_close(a, b, **CLOSE)
    assert model.null_style is None and model.music_proj is None


@pytest.mark.parametrize(
    ("options", "n_modulations", "concat"),
    [
        ({"style_injection": "modulation", "modulation_shared": True}, 1, False),
        ({"style_injection": "modulation", "modulation_shared": False}, 2, False),
        ({"style_injection": "modulation", "also_concat": True}, 1, True),
        ({"style_injection": "concat"}, 0, True),
    ],
)
def test_style_injection_variants_reach_every_style_layer(options, n_modulations, concat):
    model = tiny_denoiser(**options)
    assert (0 if model.modulations is None else len(model.modulations)) == n_modulations
    assert (model.style_concat_proj is not None) == concat
    x_t, t, music, style = inputs(3, 8)
    out = model(x_t, t, music, style)
    assert out.shape == (3, 8, POSE_DIM)
    out.square().mean().backward()
    style_layers = [m.fc for m in (model.modulations or [])]
    if concat:
        style_layers.append(model.style_concat_proj)
    for layer in style_layers:
        assert layer.weight.grad is not None and layer.weight.grad.abs().sum() > 0
    with torch.no_grad():  # the style changes the output
        assert (model(x_t, t, music, torch.randn_like(style)) - out).abs().amax() > 1e-3


def test_modulation_variants_differ_with_the_same_weights():
    official = tiny_denoiser(modulation_variant="official")
    paper = tiny_denoiser(modulation_variant="paper", seed=5)
    paper.load_state_dict(official.state_dict())
    x_t, t, music, style = inputs(2, 8)
    with torch.no_grad():
        assert (official(x_t, t, music, style) - paper(x_t, t, music, style)).abs().amax() > 1e-3


def test_concat_injection_is_a_linear_layer_over_music_and_style():
    """The music encoder's input is Linear(Da + ds -> d) of [music, style] (style repeated over frames)."""
    model = tiny_denoiser(style_injection="concat")
    x_t, t, music, style = inputs(2, 8)
    seen = {}
    hook = model.music_encoder.register_forward_pre_hook(lambda _m, args: seen.setdefault("h", args[0].detach()))
    with torch.no_grad():
        model(x_t, t, music, style)
    hook.remove()
    weight = torch.cat((model.music_proj.weight, model.style_concat_proj.weight), dim=1).detach().double()
    joint = torch.cat((music, style[:, None, :].expand(-1, 8, -1)), dim=-1).double()
    expected = joint @ weight.T + model.music_proj.bias.detach().double()
    torch.testing.assert_close(seen["h"].double(), expected, rtol=1e-5, atol=1e-6)


def test_rows_of_a_batch_are_independent():
    model = tiny_denoiser()
    x_t, t, music, style = inputs(4, 10)
    keep_m, keep_s = flags(True, False, True, True), flags(True, True, False, True)
    x2, t2, music2, style2 = inputs(4, 10, seed=9)
    for v, v2 in ((x_t, x2), (music, music2), (style, style2)):
        v2[0] = v[0]
    t2[0] = t[0]
    with torch.no_grad():
        a = model(x_t, t, music, style, keep_m, keep_s)
        b = model(x2, t2, music2, style2, flags(True, True, False, False), flags(True, False, True, False))
        alone = model(x_t[:1], t[:1], music[:1], style[:1], keep_m[:1], keep_s[:1])
    torch.testing.assert_close(a[0], b[0], **CLOSE)
    torch.testing.assert_close(a[:1], alone, rtol=1e-5, atol=1e-5)
    assert (a[1:] - b[1:]).abs().amax() > 1e-3


def test_short_window_uses_the_first_frames_of_the_null_music():
    model = tiny_denoiser()
    x_t, t, music, style = inputs(2, 5)
    dropped = flags(False, False)
    with torch.no_grad():
        a = model(x_t, t, music, style, keep_music=dropped)
        model.null_music[:, 5:] = 100.0  # frames beyond the window are never read
        b = model(x_t, t, music, style, keep_music=dropped)
        model.null_music[:, 4] = 100.0  # the window's last frame is
        c = model(x_t, t, music, style, keep_music=dropped)
    torch.testing.assert_close(a, b, **CLOSE)
    assert (a - c).abs().amax() > 1e-3


def test_attention_is_bidirectional_within_the_window():
    """Not causal: the prediction for the first frame depends on the last frame's input (and vice versa)."""
    model = tiny_denoiser()
    x_t, t, music, style = inputs(1, SEQ_LEN)
    changed = x_t.clone()
    changed[:, -1] += 1.0
    with torch.no_grad():
        a, b = model(x_t, t, music, style), model(changed, t, music, style)
    assert (a[:, 0] - b[:, 0]).abs().amax() > 1e-4
    changed = x_t.clone()
    changed[:, 0] += 1.0
    with torch.no_grad():
        c = model(changed, t, music, style)
    assert (a[:, -1] - c[:, -1]).abs().amax() > 1e-4


@pytest.mark.parametrize(
    ("options", "aligned"),
    [
        ({}, True),
        ({"rotary_placement": "input", "null_music": "output"}, True),
        ({"cross_attention_rotary": False}, False),
    ],
)
def test_the_denoiser_knows_when_in_the_window_the_music_happens(options, aligned):
    """Music at frame k conditions the frames near k, not every frame alike: with the same motion input on every
    frame and a single music event at frame k, the response to the event varies over the window only if the
    cross-attention carries positions (rotary on its queries and keys). Without them every query is identical and
    sees the music as an unordered set, so no dance could land on a beat."""
    torch.manual_seed(0)
    model = DanceDenoiser(d_model=32, n_layers=1, n_heads=2, ff_dim=64, audio_dim=8, dropout=0.0, **options).eval()
    x_t, t = torch.zeros(1, 40, POSE_DIM), torch.tensor([100])

    def response(frame: int) -> torch.Tensor:
        """The prediction with one music event at ``frame`` minus the prediction without it (40, 151)."""
        music = torch.zeros(1, 40, 8)
        music[0, frame] = 3.0
        with torch.no_grad():
            return (model(x_t, t, music) - model(x_t, t, torch.zeros_like(music)))[0]

    early, late = response(10), response(30)
    spread = (early - early.mean(0)).abs().amax()  # how much the response differs between frames
    if not aligned:  # the switch's off position: every frame responds alike, wherever the event is
        assert spread < 1e-5 and early.abs().amax() > 1e-3
        return
    assert spread > 1e-3
    # the response depends on where the event is: frame 10 hears an event at frame 10 differently from one at 30
    assert (early[10] - late[10]).abs().amax() > 1e-3


def test_aligned_music_starts_as_the_plain_denoiser_and_reaches_its_own_frame():
    """``aligned_music``: zero-initialised, so a new model predicts what the same weights without it predict; once
    trained (here: random weights), a music event at frame k reaches frame k's prediction directly, far more than
    any other frame's."""
    plain = DanceDenoiser(d_model=32, n_layers=1, n_heads=2, ff_dim=64, audio_dim=8, dropout=0.0,
                          cross_attention_rotary=False).eval()  # fmt: skip
    aligned = DanceDenoiser(d_model=32, n_layers=1, n_heads=2, ff_dim=64, audio_dim=8, dropout=0.0,
                            cross_attention_rotary=False, aligned_music=True).eval()  # fmt: skip
    missing, unexpected = aligned.load_state_dict(plain.state_dict(), strict=False)
    assert set(missing) == {"aligned_proj.weight", "aligned_proj.bias"} and not unexpected
    x_t, t = torch.randn(1, 40, POSE_DIM), torch.tensor([100])
    music = torch.randn(1, 40, 8)
    with torch.no_grad():
        assert torch.equal(aligned(x_t, t, music), plain(x_t, t, music))
        torch.nn.init.normal_(aligned.aligned_proj.weight, std=0.3)
        quiet = torch.zeros(1, 40, 8)
        event = quiet.clone()
        event[0, 10] = 3.0
        response = (aligned(x_t, t, event) - aligned(x_t, t, quiet))[0].abs().amax(-1)  # per frame
    assert response.argmax() == 10 and response[10] > 3 * torch.cat((response[:10], response[11:])).amax()
