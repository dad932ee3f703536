"""A tiny DanceDenoiser and random inputs for the model tests (importable: tests/ is on sys.path)."""

import torch

from dgsdp.model import DanceDenoiser

SEQ_LEN = 12
AUDIO_DIM = 6
STYLE_DIM = 4
POSE_DIM = 151


def tiny_denoiser(audio_dim: int = AUDIO_DIM, style_dim: int = STYLE_DIM, seed: int = 0, **kwargs) -> DanceDenoiser:
    """Random-init, eval mode, no dropout; the learned null style is made non-zero so that it is told apart from
    a zero style vector."""
    options = {"seq_len": SEQ_LEN, "d_model": 16, "n_layers": 2, "n_heads": 2, "ff_dim": 32, "dropout": 0.0,
               "music_encoder_layers": 1, **kwargs}  # fmt: skip
    with torch.random.fork_rng():  # seeded initialisation that leaves the global RNG alone
        torch.manual_seed(seed)
        model = DanceDenoiser(pose_dim=POSE_DIM, audio_dim=audio_dim, style_dim=style_dim, **options).eval()
        if model.null_style is not None:
            with torch.no_grad():
                model.null_style.normal_()
    return model


def inputs(b: int, n: int, audio_dim: int = AUDIO_DIM, style_dim: int = STYLE_DIM, seed: int = 1, per_frame=False):
    """x_t (b, n, 151), t (b,), music (b, n, audio_dim) or None, style (b, [n,] style_dim) or None."""
    g = torch.Generator().manual_seed(seed)
    x_t = torch.randn(b, n, POSE_DIM, generator=g)
    t = torch.randint(0, 1000, (b,), generator=g)
    music = torch.randn(b, n, audio_dim, generator=g) if audio_dim else None
    style_shape = (b, n, style_dim) if per_frame else (b, style_dim)
    style = torch.randn(*style_shape, generator=g) if style_dim else None
    return x_t, t, music, style
