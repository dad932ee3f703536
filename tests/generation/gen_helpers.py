"""Helpers for the generation tests: a tiny random-init model and valid 151-d motions."""

import dataclasses

import torch
from motion_helpers import random_motion  # noqa: F401 - used by the generation tests

from dgsdp.style import StyleBank
from dgsdp.trained import RunSpec
from dgsdp.training import DanceDiffusion

AUDIO_DIM = 35
STYLE_DIM = 10


def tiny_spec(style_kind: str = "onehot") -> RunSpec:
    """A tiny one-hot-style model's run spec (a style embedder config so that generation can read genres)."""
    spec = RunSpec.from_groups(
        model="small", audio_dim=AUDIO_DIM, style_dim=STYLE_DIM, style_kind=style_kind, style_bank_size=STYLE_DIM,
        n_genres=STYLE_DIM, d_model=32, n_layers=1, n_heads=2, ff_dim=64, music_encoder_layers=1, dropout=0.0,
    )  # fmt: skip
    style = {"_target_": "dgsdp.style.StyleEmbedder", "kind": style_kind, "text_encoder": None, "vocab": None}
    return dataclasses.replace(spec, style=style, audio={"_target_": "dgsdp.audio.LibrosaEncoder"})


def tiny_model() -> DanceDiffusion:
    """Random-init tiny denoiser with a one-hot style bank and a normaliser fitted on random motions."""
    torch.manual_seed(0)
    model = DanceDiffusion(tiny_spec()).eval()
    model.set_style_bank(StyleBank(torch.eye(STYLE_DIM), torch.arange(STYLE_DIM), STYLE_DIM))
    model.normalizer.fit(torch.cat([random_motion(400, seed=s) for s in range(3)]))
    return model


SEQUENCES = {"train": ["gBR_sBM_cAll_d04_mBR0_ch01", "gKR_sBM_cAll_d28_mKR2_ch01"],
             "test": ["gBR_sBM_cAll_d05_mBR0_ch02"]}  # fmt: skip


def write_click_song(path, seconds: float, bpm: float = 120.0, rate_hz: int = 8000) -> None:
    """A click on every beat (a short decaying tone), mono 16-bit wav."""
    import numpy as np
    import soundfile as sf

    n = int(seconds * rate_hz)
    audio = np.zeros(n, dtype=np.float32)
    click = np.sin(2 * np.pi * 1000 * np.arange(400) / rate_hz) * np.exp(-np.arange(400) / 80)
    for beat in np.arange(0, seconds, 60.0 / bpm):
        i = int(beat * rate_hz)
        audio[i : i + 400] += click[: max(0, min(400, n - i))]
    sf.write(path, 0.5 * audio, rate_hz, subtype="PCM_16")


def make_tiny_dataset(root, seconds: float = 8.0) -> None:
    """Three short sequences in the AIST++ layout (60 FPS SMPL pickles, wavs, split lists)."""
    import pickle

    import numpy as np

    (root / "motions").mkdir(parents=True)
    (root / "wavs").mkdir()
    (root / "splits").mkdir()
    n = int(seconds * 60)
    t = np.arange(n) / 60.0
    for split, names in SEQUENCES.items():
        (root / "splits" / f"crossmodal_{split}.txt").write_text("\n".join(names) + "\n")
        for k, name in enumerate(names):
            rng = np.random.default_rng(k + 10 * (split == "test"))
            poses = 0.3 * np.sin(2 * np.pi * (1 + k) * t[:, None] / 2 + rng.uniform(0, 6, 72))
            trans = np.stack([0.1 * np.sin(t), 0.9 + 0.02 * np.sin(4 * t), 0.1 * np.cos(t)], axis=1)
            with open(root / "motions" / f"{name}.pkl", "wb") as f:
                pickle.dump({"smpl_poses": poses.astype(np.float32), "smpl_trans": trans.astype(np.float32),
                             "smpl_scaling": np.ones(1, np.float32), "smpl_loss": 0.0}, f)  # fmt: skip
            music_id = name.split("_")[4]
            if not (root / "wavs" / f"{music_id}.wav").exists():
                write_click_song(root / "wavs" / f"{music_id}.wav", seconds)


def train_tiny_checkpoint(tmp, overrides: tuple[str, ...] = (), style: str = "onehot") -> str:
    """Train the debug=tiny model for a few steps on a hand-made dataset (in ``tmp / "data"``); returns the
    checkpoint path. ``style="prompt"``: a model that also takes free-text styles (the bundled MiniLM)."""
    from hydra import compose, initialize_config_dir

    from dgsdp.cli.train import train
    from dgsdp.resources import CONFIG_DIR

    make_tiny_dataset(tmp / "data")
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose(
            "train",
            overrides=[
                "debug=tiny", f"style={style}", "logger=none", f"data.root={tmp / 'data'}", "data.synthetic=null",
                f"paths.cache_dir={tmp / 'cache'}", f"paths.output_dir={tmp / 'run'}", "trainer.max_steps=2",
                "~callbacks.progress", "run_name=tiny", *overrides,
            ],
        )  # fmt: skip
    result = train(cfg)
    return result["checkpoint"]
