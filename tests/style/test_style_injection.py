"""Style modulation (DGSDP Eq. 9, two variants) and style concatenation, against hand computations."""

from __future__ import annotations

import math

import pytest
import torch

from dgsdp.style.injection import StyleModulation, concat_style


def hand_module(variant: str) -> StyleModulation:
    """d_model = style_dim = 2 with FC weight [[1, 0], [0, 2]] and bias [0.5, -1]."""
    module = StyleModulation(d_model=2, style_dim=2, variant=variant)
    with torch.no_grad():
        module.fc.weight.copy_(torch.tensor([[1.0, 0.0], [0.0, 2.0]]))
        module.fc.bias.copy_(torch.tensor([0.5, -1.0]))
    return module


def test_modulation_hand_case_both_variants() -> None:
    # x = (3, 4): ||x|| = 5, r = 2^-1/2, x / (||x|| r) = (3, 4) * sqrt(2) / 5.
    # s = (1, 1): FC(s) = (1 + 0.5, 2 - 1) = (1.5, 1).
    x = torch.tensor([[[3.0, 4.0]]])
    s = torch.tensor([[1.0, 1.0]])
    sm = torch.tensor([[[3 * math.sqrt(2) / 5 * 1.5, 4 * math.sqrt(2) / 5 * 1.0]]])
    torch.testing.assert_close(hand_module("paper")(x, s), sm)
    torch.testing.assert_close(hand_module("official")(x, s), x + sm)
    torch.testing.assert_close(hand_module("official").modulation(x, s), sm)


def test_modulation_is_rms_normalisation_times_style() -> None:
    torch.manual_seed(0)
    module = StyleModulation(d_model=8, style_dim=3, variant="paper")
    with torch.no_grad():
        module.fc.weight.zero_()
        module.fc.bias.fill_(1.0)
    x = torch.randn(2, 5, 8) * 7.0
    out = module(x, torch.randn(2, 3))
    rms = out.pow(2).mean(-1).sqrt()
    torch.testing.assert_close(rms, torch.ones(2, 5))
    torch.testing.assert_close(out, x / x.pow(2).mean(-1, keepdim=True).sqrt())


def test_per_frame_style_matches_frame_by_frame() -> None:
    torch.manual_seed(1)
    module = StyleModulation(d_model=8, style_dim=4)
    x = torch.randn(2, 5, 8)
    style = torch.randn(2, 5, 4)
    out = module(x, style)
    assert out.shape == (2, 5, 8)
    for t in range(5):
        torch.testing.assert_close(out[:, t : t + 1], module(x[:, t : t + 1], style[:, t]))
    constant = torch.randn(2, 4)
    torch.testing.assert_close(module(x, constant), module(x, constant[:, None].expand(2, 5, 4)))


def test_modulation_zero_input_and_gradients() -> None:
    module = StyleModulation(d_model=4, style_dim=3)
    out = module(torch.zeros(1, 2, 4), torch.ones(1, 3))
    assert torch.isfinite(out).all()
    x = torch.randn(1, 2, 4, requires_grad=True)
    module(x, torch.ones(1, 3)).sum().backward()
    assert module.fc.weight.grad is not None and module.fc.weight.grad.abs().sum() > 0


def test_modulation_shape_errors() -> None:
    module = StyleModulation(d_model=4, style_dim=3)
    with pytest.raises(ValueError):
        module(torch.zeros(1, 2, 5), torch.zeros(1, 3))
    with pytest.raises(ValueError):
        module(torch.zeros(1, 2, 4), torch.zeros(1, 2))
    with pytest.raises(ValueError):
        module(torch.zeros(1, 2, 4), torch.zeros(1, 3, 3))
    with pytest.raises(ValueError):
        StyleModulation(4, 3, variant="other")


def test_concat_style() -> None:
    music = torch.randn(2, 5, 7)
    style = torch.randn(2, 3)
    out = concat_style(music, style)
    assert out.shape == (2, 5, 10)
    assert torch.equal(out[..., :7], music)
    assert torch.equal(out[..., 7:], style[:, None].expand(2, 5, 3))
    per_frame = torch.randn(2, 5, 3)
    assert torch.equal(concat_style(music, per_frame)[..., 7:], per_frame)
    assert concat_style(music, torch.zeros(2, 0)).shape == (2, 5, 7)
    with pytest.raises(ValueError):
        concat_style(music, torch.randn(2, 4, 3))
