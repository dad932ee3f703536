"""Every experiment config composes and instantiates its (paper-size) model."""

from pathlib import Path

import pytest

from dgsdp.cli.config import compose_config
from dgsdp.cli.train import audio_encoder_from_config, style_embedder_from_config
from dgsdp.resources import CONFIG_DIR
from dgsdp.trained.spec import RunSpec
from dgsdp.training import DanceDiffusion

EXPERIMENTS = sorted(p.stem for p in (CONFIG_DIR / "experiment").glob("*.yaml"))
# the quick start's ablation (sweeps/quickstart.yaml): small model, one change per row;
# row: (velocity loss weight, audio.rhythm_only, audio.beat_phase, steps, pause loss weight, data.tempo_augment,
# data.synthetic.offbeats, model.aligned_music, model.dropout, loss.root, style.prompts_file,
# generation.style_text_temperature and style_text_reading: how generate.py reads free text with the row's model by
# default, model.speed_conditioning, optimizer.schedule, model.movement_channels, optimizer.style_lr_scale,
# data.synthetic.movement_variation, the window's frames: model.seq_len = data.window_seconds x 30)
QUICKSTART_ROWS = {
    "quickstart_row0": (0.0, False, False, 500, 0.0, None, True, False, 0.1, 0.0, None, None, None, False, None, [], 1.0, False, 150),
    "quickstart_row1": (2.964, False, False, 500, 0.0, None, True, False, 0.1, 0.0, None, None, None, False, None, [], 1.0, False, 150),
    "quickstart_row2": (2.964, True, False, 500, 0.0, None, True, False, 0.1, 0.0, None, None, None, False, None, [], 1.0, False, 150),
    "quickstart_row3": (2.964, True, True, 500, 0.0, None, True, False, 0.1, 0.0, None, None, None, False, None, [], 1.0, False, 150),
    "quickstart_row4": (2.964, True, False, 1000, 0.0, None, True, False, 0.1, 0.0, None, None, None, False, None, [], 1.0, False, 150),
    "quickstart_row5": (2.964, True, False, 1000, 6.0, None, True, False, 0.1, 0.0, None, None, None, False, None, [], 1.0, False, 150),
    "quickstart_row6": (2.964, True, False, 1000, 6.0, [0.8, 1.25], True, False, 0.1, 0.0, None, None, None, False, None, [], 1.0, False, 150),
    "quickstart_row7": (2.964, True, False, 1000, 6.0, None, False, False, 0.1, 0.0, None, None, None, False, None, [], 1.0, False, 150),
    "quickstart_row8": (2.964, True, False, 1000, 6.0, None, True, True, 0.1, 0.0, None, None, None, False, None, [], 1.0, False, 150),
    "quickstart_row9": (2.964, True, False, 1000, 6.0, None, True, False, 0.0, 0.0, None, None, None, False, None, [], 1.0, False, 150),
    "quickstart_row10": (2.964, True, False, 4000, 6.0, None, True, False, 0.0, 10.0, None, 0.02, None, False, None, [], 1.0, False, 150),
    "quickstart_row11": (2.964, True, False, 4000, 6.0, None, True, False, 0.0, 10.0, "aistpp_augmented", 0.02, None, False, None, [], 1.0, False, 150),
    "quickstart_row12": (2.964, True, False, 6000, 6.0, None, True, False, 0.0, 10.0, None, 0.02, None, False, None, [], 1.0, False, 150),
    "quickstart_row13": (2.964, True, False, 6000, 6.0, None, True, False, 0.0, 10.0, None, None, "router", True, None, [], 1.0, False, 150),
    "quickstart_row14": (2.964, True, False, 1000, 6.0, None, True, False, 0.0, 10.0, None, None, "router", True, None, [], 1.0, False, 150),
    "quickstart_row15": (2.964, True, False, 1000, 6.0, None, True, False, 0.0, 10.0, None, None, "router", True,
                         {"warmup_steps": 50, "decay": "cosine", "final_lr_ratio": 0.05}, [], 1.0, False, 150),
    "quickstart_row16": (2.964, True, False, 6000, 6.0, None, True, False, 0.0, 10.0, None, None, "router", True, None,
                         ["speed", "level", "arms", "travel", "turning"], 1.0, False, 150),
    "quickstart_row17": (2.964, True, False, 1000, 6.0, None, True, False, 0.0, 10.0, None, None, "router", True, None, [],
                         10.0, False, 150),
    "quickstart_row18": (2.964, True, False, 6000, 6.0, None, True, False, 0.0, 10.0, None, None, "router", True, None,
                         ["speed", "level", "arms", "travel", "turning"], 1.0, True, 150),
    "quickstart_row19": (2.964, True, False, 2750, 6.0, None, True, False, 0.0, 10.0, None, None, "router", True, None, [],
                         10.0, False, 60),
    "quickstart_row20": (2.964, True, False, 3500, 6.0, None, True, False, 0.0, 10.0, None, None, "router", True, None, [],
                         10.0, False, 45),
    "quickstart_row21": (2.964, True, False, 12000, 6.0, None, True, False, 0.0, 10.0, None, None, "router", True, None,
                         [], 10.0, False, 45),
    "quickstart_row22": (2.964, True, False, 12000, 6.0, None, True, False, 0.0, 10.0, None, None, "router", True, None,
                         ["speed", "level", "arms"], 10.0, False, 45),
}  # fmt: skip


def _window_frames(cfg) -> int:
    frames = round(cfg.data.window_seconds * cfg.data.fps)
    assert cfg.model.seq_len == frames, "the model's window and the data's must be the same frames"
    return frames


def _row(cfg) -> tuple:
    tempo = cfg.data.tempo_augment
    return (
        cfg.loss.velocity, cfg.audio.rhythm_only, cfg.audio.beat_phase, cfg.trainer.max_steps, cfg.loss.pause,
        tempo if tempo is None else list(tempo), cfg.data.synthetic.offbeats, cfg.model.aligned_music,
        cfg.model.dropout, cfg.loss.root, cfg.style.prompts_file, cfg.generation.style_text_temperature,
        cfg.generation.style_text_reading, cfg.model.speed_conditioning,
        None if cfg.optimizer.get("schedule") is None else dict(cfg.optimizer.schedule),
        list(cfg.model.movement_channels), cfg.optimizer.get("style_lr_scale", 1.0),
        cfg.data.synthetic.get("movement_variation", False), _window_frames(cfg),
    )  # fmt: skip


PAPER_SIZE = [name for name in EXPERIMENTS if name not in QUICKSTART_ROWS]
PAPER_ROWS = {
    # row: (audio, style kind, injection mode)
    "table4_row0": ("jukebox", "prompt", "modulation"),
    "table4_row1": ("encodec", "prompt", "modulation"),
    "table4_row2": ("librosa", "prompt", "modulation"),
    "table4_row3": ("jukebox", "genre", "modulation"),
    "table4_row4": ("jukebox", "prompt", "concat"),
    "table4_row5": ("jukebox", "none", None),
    "table5_row1": ("jukebox", "prompt", "modulation"),
    "table5_row2": ("jukebox", "genre", "modulation"),
    "table5_row3": ("jukebox", "onehot", "modulation"),
    "table5_row4": ("jukebox", "prompt", "concat"),
    "table5_row5": ("jukebox", "genre", "concat"),
    "table5_row6": ("jukebox", "onehot", "concat"),
    "edge": ("jukebox", "none", None),
    "dgsdp": ("jukebox", "prompt", "modulation"),
    "finedance_edge": ("librosa", "none", None),
    "finedance_dgsdp": ("jukebox", "prompt", "modulation"),
}


def test_experiment_folder_holds_every_paper_row():
    assert EXPERIMENTS, "conf/experiment is empty"
    assert set(PAPER_ROWS) <= set(EXPERIMENTS)


@pytest.mark.parametrize("name", PAPER_SIZE)
def test_experiment_composes_and_builds_paper_size_model(name, tmp_path):
    cfg = compose_config("train", [f"experiment={name}"], output_dir=tmp_path)
    audio = audio_encoder_from_config(cfg)  # builds the encoder object; weights load only when encoding
    style = style_embedder_from_config(cfg)
    bank_size = len(style.bank_texts()[0]) if style.dim else 0
    spec = RunSpec.from_config(cfg, audio_encoder=audio, style_embedder=style, style_bank_size=bank_size, groups={})
    model = DanceDiffusion(spec)
    n_params = sum(p.numel() for p in model.denoiser.parameters())
    print(f"{name}: {n_params / 1e6:.2f}M parameters")
    # The papers' counts (EDGE ~49.5M, DGSDP 49.7M) are with 4800-d Jukebox features; other encoders change only
    # the music input projection (audio_dim x 512 weights).
    jukebox_equivalent = n_params + (4800 - audio.feature_dim) * cfg.model.d_model
    assert 48.5e6 <= jukebox_equivalent <= 50.5e6
    if name in PAPER_ROWS:
        audio_name, kind, injection = PAPER_ROWS[name]
        assert audio.name == audio_name
        assert style.kind == kind
        assert cfg.run_name == name
        assert cfg.generation.style_text_temperature is None  # free text by its own embedding, as the papers
        if injection is not None:
            assert spec.model["style_injection"] == injection
            assert model.denoiser.use_modulation == (injection == "modulation")
        else:
            assert model.denoiser.style_dim == 0
        assert cfg.model.d_model == 512 and cfg.model.n_layers == 8 and cfg.model.n_heads == 8
        assert cfg.model.ff_dim == 1024 and cfg.data.batch_size == 128


@pytest.mark.parametrize("name", sorted(QUICKSTART_ROWS))
def test_quickstart_rows_change_one_thing_each(name, tmp_path):
    from dgsdp.quickstart import QUICKSTART_EXPERIMENT, QUICKSTART_TRAINING

    cfg = compose_config("train", [f"experiment={name}"], output_dir=tmp_path)
    assert _row(cfg) == QUICKSTART_ROWS[name]
    # the data without off-beat layers or with movement variation lives in its own folder: rows of one sweep never
    # regenerate each other's
    default = compose_config("train", [], output_dir=tmp_path).data
    own_folder = not cfg.data.synthetic.offbeats or cfg.data.synthetic.get("movement_variation", False)
    assert (cfg.data.root == default.root) != own_folder
    assert cfg.data.synthetic_root == cfg.data.root
    assert cfg.loss.simple == 1.0 and cfg.loss.fk == 0.0 and cfg.loss.foot == 0.0
    assert (cfg.optimizer.lr, cfg.model.ema_decay) == (1e-3, 0.98)
    assert cfg.run_name == name and cfg.model.d_model == compose_config("train", []).model.d_model  # small model
    spec = RunSpec.from_config(
        cfg, audio_encoder=audio_encoder_from_config(cfg), style_embedder=style_embedder_from_config(cfg),
        style_bank_size=0, groups={},
    )  # fmt: skip
    assert spec.conditioning.audio_dim == 35 + 2 * cfg.audio.beat_phase
    # the quick start trains its experiment's row
    quick = compose_config("train", list(QUICKSTART_TRAINING), output_dir=tmp_path)
    assert _row(quick) == QUICKSTART_ROWS[QUICKSTART_EXPERIMENT]
    # the descriptions free text is read through: the augmented ones, and from row 20 on 24 more per genre
    descriptions = cfg.generation.style_text_descriptions
    if cfg.generation.style_text_reading == "router" or cfg.generation.style_text_temperature is not None:
        assert descriptions == (
            "aistpp_reader"
            if name in ("quickstart_row20", "quickstart_row21", "quickstart_row22")
            else "aistpp_augmented"
        )
    else:
        assert descriptions is None


def test_edge_parameter_count_matches_paper(tmp_path):
    cfg = compose_config("train", ["experiment=edge"], output_dir=tmp_path)
    spec = RunSpec.from_config(
        cfg, audio_encoder=audio_encoder_from_config(cfg), style_embedder=style_embedder_from_config(cfg),
        style_bank_size=0, groups={},
    )  # fmt: skip
    model = DanceDiffusion(spec)
    n_params = sum(p.numel() for p in model.denoiser.parameters())
    print(f"EDGE-size denoiser: {n_params:,} parameters")
    assert abs(n_params - 49.5e6) <= 1e6
    assert Path(CONFIG_DIR / "experiment" / "edge.yaml").is_file()


def test_finedance_experiments_read_finedance(tmp_path):
    from dgsdp.style.vocab import GenreVocab

    edge = compose_config("train", ["experiment=finedance_edge"], output_dir=tmp_path)
    assert edge.data._target_ == "dgsdp.data.finedance.FineDanceDataModule" and edge.data.finedance.joints == "body"
    assert (edge.audio.loudness_lufs, edge.audio.mfcc_fmax_hz, edge.audio.standardize) == (None, None, "none")
    assert audio_encoder_from_config(edge).output_dim == 35
    assert dict(edge.loss) == dict(compose_config("train", ["experiment=edge"], output_dir=tmp_path).loss)
    assert edge.model.rotary_placement == "input" and edge.model.null_music == "output"  # EDGE's architecture
    dgsdp = compose_config("train", ["experiment=finedance_dgsdp"], output_dir=tmp_path)
    style = style_embedder_from_config(dgsdp)
    assert style.vocab == GenreVocab.named("finedance") and style.prompts_file.name == "finedance.yaml"
    # the tiny CPU variant of each composes: a small model on the CPU
    tiny = compose_config("train", ["experiment=finedance_edge", "debug=tiny", "trainer=cpu"], output_dir=tmp_path)
    assert tiny.model.d_model == 32 and tiny.trainer.accelerator == "cpu" and tiny.trainer.precision == "32-true"
