"""Helpers for the generation tests: a tiny random-init model and valid 151-d motions."""

import torch

from dgsdp.motion import axis_angle_to_matrix, pack_pose
from dgsdp.style import StyleBank
from dgsdp.training.module import DanceDiffusion

AUDIO_DIM = 35
STYLE_DIM = 10


def random_motion(n: int, seed: int = 0) -> torch.Tensor:
    """A valid unnormalised motion (n, 151): random joint rotations, a wandering root, binary contacts."""
    g = torch.Generator().manual_seed(seed)
    rot = axis_angle_to_matrix(0.5 * torch.randn(n, 24, 3, generator=g, dtype=torch.float64))
    trans = torch.randn(n, 3, generator=g, dtype=torch.float64).cumsum(0) * 0.01
    contacts = (torch.rand(n, 4, generator=g) > 0.5).double()
    return pack_pose(contacts, trans, rot).float()


def tiny_hparams(style_kind: str = "onehot") -> dict:
    return {
        "model": {"seq_len": 150, "d_model": 32, "n_layers": 1, "n_heads": 2, "ff_dim": 64,
                  "music_encoder_layers": 1, "dropout": 0.0, "style_injection": "modulation"},
        "conditioning": {"audio_dim": AUDIO_DIM, "style_dim": STYLE_DIM, "style_bank_size": STYLE_DIM,
                         "n_genres": STYLE_DIM, "style_kind": style_kind},
        "diffusion": {},
        "config": {"style": {"_target_": "dgsdp.style.StyleEmbedder", "_recursive_": False, "kind": style_kind,
                             "text_encoder": None, "vocab": None, "cache_dir": None}},
    }  # fmt: skip


def tiny_model() -> DanceDiffusion:
    """Random-init tiny denoiser with a one-hot style bank and a normaliser fitted on random motions."""
    torch.manual_seed(0)
    model = DanceDiffusion(tiny_hparams()).eval()
    model.set_style_bank(StyleBank(torch.eye(STYLE_DIM), torch.arange(STYLE_DIM), STYLE_DIM))
    model.normalizer.fit(torch.cat([random_motion(400, seed=s) for s in range(3)]))
    return model
