"""``sampling=edge``: EDGE's long-form procedure, checked against the procedure written out here from EDGE's
description (model/diffusion.py ``long_ddim_sample``, EDGE.py ``render_sample``); the same check against EDGE's own
code is ``python -m dgsdp.interop.edge verify`` (tests/interop/test_edge_verify_slow.py)."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation, Slerp

from dgsdp.cli.config import compose_config
from dgsdp.generation import stitch_windows
from dgsdp.generation.longform import DanceRequest, sample_items
from dgsdp.motion import matrix_to_6d, sixd_to_matrix
from dgsdp.sampling import SamplingSettings
from dgsdp.trained.spec import RunSpec
from dgsdp.training.module import DanceDiffusion

WINDOW, HALF, AUDIO = 20, 10, 7


@pytest.fixture(scope="module")
def edge_like_model() -> DanceDiffusion:
    torch.manual_seed(0)
    spec = RunSpec.from_groups(
        model="small", audio_dim=AUDIO, style_dim=0, d_model=32, n_layers=2, n_heads=4, ff_dim=64, seq_len=WINDOW,
        rotary_placement="input", null_music="output",
    )  # fmt: skip
    model = DanceDiffusion(spec).eval()
    with torch.no_grad():  # a denoiser that is far from the identity, so that every step matters
        for p in model.ema.module.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return model


def edge_settings() -> SamplingSettings:
    return SamplingSettings.from_config(compose_config("generate", ["sampling=edge"]).sampling)


def test_the_edge_preset_is_edges_test_procedure():
    s = edge_settings()
    assert (s.method, s.steps, s.eta, s.guidance.music, s.clip_x0, s.longform) == ("ddim", 50, 1.0, 2.0, 1.0, "edge")
    assert (s.guidance.longform_ramp_fraction, s.stride_frames) == (0.5, 75)
    assert s.project_rotations == "none"  # the network's 6D rotations as it gives them
    assert SamplingSettings().project_rotations == "root"


def edge_long_ddim(model: DanceDiffusion, cond: torch.Tensor, weight: float, steps: int = 50) -> torch.Tensor:
    """EDGE's long_ddim_sample over our denoiser: DDIM with eta 1, x0 clipped to [-1, 1], guidance weights
    clip(linspace(0, 2w, n), max=w), the first half of window i + 1 overwritten by the second half of window i
    after every step whose time is above 0, the last step returning x0."""
    den, ab = model.ema.module, model.diffusion.alpha_bar.double()
    times = list(reversed(torch.linspace(-1, 999, steps=steps + 1).int().tolist()))
    weights = np.clip(np.linspace(0, weight * 2, steps), None, weight)
    b = cond.shape[0]
    x = torch.randn(b, WINDOW, 151)
    keep, drop = torch.ones(b, dtype=torch.bool), torch.zeros(b, dtype=torch.bool)
    for time, time_next, w in zip(times[:-1], times[1:], weights):
        t = torch.full((b,), time, dtype=torch.long)
        with torch.no_grad():
            unc, con = den(x, t, cond, keep_music=drop), den(x, t, cond, keep_music=keep)
        x0 = (unc + (con - unc) * float(w)).clamp(-1, 1)
        eps = ((1 / ab[time]).sqrt() * x - x0) / (1 / ab[time] - 1).sqrt()
        if time_next < 0:
            x = x0
            continue
        alpha, alpha_next = ab[time], ab[time_next]
        sigma = ((1 - alpha / alpha_next) * (1 - alpha_next) / (1 - alpha)).sqrt()
        c = (1 - alpha_next - sigma**2).sqrt()
        x = (x0 * alpha_next.sqrt() + c * eps + sigma * torch.randn_like(x)).float()
        x[1:, :HALF] = x[:-1, HALF:]
    return x


def test_edge_longform_is_edges_procedure(edge_like_model):
    n_windows = 4
    music = torch.randn(HALF * (n_windows - 1) + WINDOW, AUDIO)
    cond = torch.stack([music[i * HALF : i * HALF + WINDOW] for i in range(n_windows)])
    torch.manual_seed(7)
    expected = edge_long_ddim(edge_like_model, cond, 2.0)
    s = edge_settings()
    torch.manual_seed(7)
    (ours,) = sample_items(
        edge_like_model.sampler(), edge_like_model.normalizer, [DanceRequest(len(music), music=music, seed=None)],
        window=WINDOW, stride=HALF, method=s.method, steps=s.steps, eta=s.eta, guidance=s.guidance_for(long=True),
        longform=s.longform, clip_x0=s.clip_x0, windows=True,
    )  # fmt: skip
    torch.testing.assert_close(ours[0], expected, atol=1e-4, rtol=0)
    # the project's fused windows are another procedure: they must not pass the same check
    torch.manual_seed(7)
    (fused,) = sample_items(
        edge_like_model.sampler(), edge_like_model.normalizer, [DanceRequest(len(music), music=music, seed=None)],
        window=WINDOW, stride=HALF, method=s.method, steps=s.steps, eta=s.eta, guidance=s.guidance_for(long=True),
        longform="fuse", clip_x0=s.clip_x0, windows=True,
    )  # fmt: skip
    assert (fused[0] - expected).abs().max() > 0.05


def test_stitching_is_edges_final_cross_fade():
    """EDGE's render_sample: root positions faded with linspace(1, 0) / linspace(0, 1) over the overlap and summed,
    rotations slerped with weights linspace(0, 1) (here scipy's Slerp), first half of the first window and second
    half of the last kept."""
    g = torch.Generator().manual_seed(3)
    windows = torch.randn(3, WINDOW, 151, generator=g, dtype=torch.float64)
    windows[..., 7:] = matrix_to_6d(sixd_to_matrix(windows[..., 7:].reshape(3, WINDOW, 24, 6))).reshape(3, WINDOW, 144)
    out = stitch_windows(windows, HALF)
    assert out.shape == (WINDOW + HALF * 2, 151)
    ramp = np.linspace(0, 1, HALF)
    rot = sixd_to_matrix(windows[..., 7:].reshape(3, WINDOW, 24, 6)).numpy()
    got = sixd_to_matrix(out[:, 7:].reshape(-1, 24, 6)).numpy()
    for i in range(2):
        pos = windows[i, HALF:, 4:7].numpy() * (1 - ramp)[:, None] + windows[i + 1, :HALF, 4:7].numpy() * ramp[:, None]
        seg = slice(HALF * (i + 1), HALF * (i + 2))
        np.testing.assert_allclose(out[seg, 4:7].numpy(), pos, atol=1e-9)
        for j in (0, 5, 23):
            for f in range(HALF):
                pair = Rotation.from_matrix([rot[i, HALF + f, j], rot[i + 1, f, j]])
                want = Slerp([0, 1], pair)([ramp[f]]).as_matrix()[0]
                np.testing.assert_allclose(got[HALF * (i + 1) + f, j], want, atol=1e-6)
    np.testing.assert_allclose(out[:HALF].numpy(), windows[0, :HALF].numpy())
    np.testing.assert_allclose(out[-HALF:, 4:].numpy(), windows[-1, HALF:, 4:].numpy(), atol=1e-9)
