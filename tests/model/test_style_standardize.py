"""model.style_standardize: style vectors centred on the training bank and scaled to a set RMS per dimension."""

import numpy as np
import pytest
import torch

from dgsdp.model import DanceDenoiser

SMALL = dict(d_model=32, n_layers=2, n_heads=2, ff_dim=64, seq_len=20, audio_dim=5, style_dim=6)


def _bank(n: int = 8) -> torch.Tensor:
    g = torch.Generator().manual_seed(1)
    return torch.randn(n, 6, generator=g) * 0.1 + torch.linspace(1.0, 2.0, 6)  # a large shared component


def test_without_the_switch_the_denoiser_is_unchanged():
    torch.manual_seed(0)
    before = DanceDenoiser(**SMALL)
    off = DanceDenoiser(**SMALL, style_standardize=None)
    assert before.state_dict().keys() == off.state_dict().keys()  # existing checkpoints load as they did
    off.set_style_statistics(_bank())  # a no-op
    on = DanceDenoiser(**SMALL, style_standardize=0.5)
    assert {"style_mean", "style_scale"} <= set(on.state_dict())


def test_statistics_against_numpy():
    model = DanceDenoiser(**SMALL, style_standardize=0.5)
    bank = _bank()
    model.set_style_statistics(bank)
    b = bank.double().numpy()
    centred = b - b.mean(axis=0)
    expected = centred * (0.5 / np.sqrt(np.mean(centred**2)))
    got = ((bank - model.style_mean) * model.style_scale).double().numpy()
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
    assert np.sqrt(np.mean(got**2)) == pytest.approx(0.5, rel=1e-5)


def test_the_prediction_sees_the_standardised_style():
    torch.manual_seed(0)
    on = DanceDenoiser(**SMALL, style_standardize=1.0).eval()
    bank = _bank()
    on.set_style_statistics(bank)
    off = DanceDenoiser(**SMALL).eval()
    off.load_state_dict({k: v for k, v in on.state_dict().items() if not k.startswith("style_")})
    x, t, music = torch.randn(2, 20, 151), torch.tensor([3, 500]), torch.randn(2, 20, 5)
    style = bank[:2]
    standardised = (style - bank.mean(0)) / (bank - bank.mean(0)).pow(2).mean().sqrt()
    with torch.no_grad():
        a = on(x, t, music, style)
        assert torch.allclose(a, off(x, t, music, standardised), atol=1e-5)
        assert not torch.allclose(a, off(x, t, music, style), atol=1e-3)
        keep = torch.ones(2, dtype=torch.bool)
        assert torch.allclose(a, on(x, t, cond=on.condition(music, style, keep, keep)), atol=1e-5)
        dropped = torch.zeros(2, dtype=torch.bool)  # a dropped style is the learned null, not standardised
        assert torch.allclose(on(x, t, music, style, keep_style=dropped), off(x, t, music, style, keep_style=dropped))


@pytest.mark.parametrize("value", [0.0, -1.0, 1e9])
def test_bad_values_are_refused(value):
    with pytest.raises(ValueError, match="style_standardize"):
        DanceDenoiser(**SMALL, style_standardize=value)


def test_a_bank_of_equal_vectors_is_refused():
    model = DanceDenoiser(**SMALL, style_standardize=1.0)
    with pytest.raises(ValueError, match="all equal"):
        model.set_style_statistics(torch.ones(4, 6))
