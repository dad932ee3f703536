"""sampling.guidance.rescale: the guided prediction's movement over time scaled back to the conditional one's."""

import pytest
import torch

from dgsdp.errors import ConfigError
from dgsdp.sampling import SamplingSettings
from dgsdp.sampling.sampler import Condition, Guidance, Sampler, rescale_guided


def test_rescale_keeps_the_mean_pose_and_takes_the_conditional_spread():
    torch.manual_seed(0)
    guided = torch.randn(2, 40, 5) * 3 + 2
    conditional = torch.randn(2, 40, 5) * 0.5
    full = rescale_guided(guided, conditional, 1.0)
    assert torch.allclose(full.mean(1), guided.mean(1), atol=1e-5)
    assert torch.allclose(full.std(1), conditional.std(1), atol=1e-5)
    assert torch.equal(rescale_guided(guided, conditional, 0.0), guided)
    half = rescale_guided(guided, conditional, 0.5)
    assert torch.allclose(half, 0.5 * full + 0.5 * guided, atol=1e-6)
    one_frame = guided[:, :1]
    assert torch.equal(rescale_guided(one_frame, conditional[:, :1], 1.0), one_frame)


class _Linear(torch.nn.Module):
    """x0 = music (+ x_t * 0): the music-free pass predicts zeros, so guidance w scales the music by w."""

    def forward(self, x_t, t, music=None, style=None, keep_music=None, keep_style=None):
        return x_t * 0 + music * keep_music[:, None, None].to(music.dtype)


def test_the_sampler_rescales_only_guided_predictions():
    from dgsdp.diffusion import GaussianDiffusion

    sampler = Sampler(_Linear(), GaussianDiffusion(num_steps=10), style_guidance=False, clip_x0=False)
    music = torch.linspace(-1, 1, 12).reshape(1, 12, 1).expand(1, 12, 3).contiguous()
    x_t, t = torch.zeros(1, 12, 3), torch.tensor([5])
    plain = sampler.predict_x0(x_t, t, Condition(music=music), Guidance(3.0))
    assert torch.allclose(plain, 3 * music)
    rescaled = sampler.predict_x0(x_t, t, Condition(music=music), Guidance(3.0, rescale=1.0))
    assert torch.allclose(rescaled, music, atol=1e-5)  # the movement of the conditional prediction, same mean (0)
    one_pass = sampler.predict_x0(x_t, t, Condition(music=music), Guidance(1.0, rescale=1.0))
    assert torch.allclose(one_pass, music)


def test_settings_carry_and_check_the_rescale():
    settings = SamplingSettings.from_config({"guidance": {"rescale": 0.7}})
    assert settings.guidance_for(long=True).rescale == 0.7
    assert settings.guidance_for(long=False).at(0, 10, 900, masked=False).rescale == 0.7
    with pytest.raises(ConfigError, match="rescale must lie in"):
        SamplingSettings.from_config({"guidance": {"rescale": 1.5}})
