"""model.style_film: the style also enters every FiLM through the diffusion step's condition."""

import torch

from dgsdp.model import DanceDenoiser

SMALL = dict(d_model=32, n_layers=2, n_heads=2, ff_dim=64, seq_len=20, audio_dim=5, style_dim=6)


def test_without_the_switch_the_denoiser_is_unchanged():
    torch.manual_seed(0)
    before = DanceDenoiser(**SMALL)
    torch.manual_seed(0)
    off = DanceDenoiser(**SMALL, style_film=False)
    assert before.state_dict().keys() == off.state_dict().keys()  # existing checkpoints load as they did
    assert "style_film_proj.weight" in DanceDenoiser(**SMALL, style_film=True).state_dict()


def test_style_changes_the_prediction_and_a_constant_schedule_equals_one_style():
    torch.manual_seed(0)
    model = DanceDenoiser(**SMALL, style_film=True).eval()
    with torch.no_grad():
        model.modulations = None  # only the FiLM path carries the style here
    x, t, music = torch.randn(2, 20, 151), torch.tensor([3, 500]), torch.randn(2, 20, 5)
    style = torch.randn(2, 6)
    a = model(x, t, music, style)
    assert not torch.allclose(a, model(x, t, music, style + 1.0))
    per_frame = style[:, None, :].expand(2, 20, 6)
    assert torch.allclose(a, model(x, t, music, per_frame), atol=1e-5)
    keep = torch.ones(2, dtype=torch.bool)
    cond = model.condition(music, style, keep, keep)
    assert torch.allclose(a, model(x, t, cond=cond), atol=1e-5)  # sampling's cached conditioning agrees
