"""Movement that varies within a genre (``data.synthetic.movement_variation``): each eight-count block of a dance
travels, turns and sinks by its own amount, and the dataset without the option stays the one before it."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from dgsdp.data.synthetic import MANIFEST, generate_synthetic_aistpp, main, outdated_synthetic, synthetic_folder
from dgsdp.data.synthetic_motion import (
    DANCE_STYLES,
    VARIATION_LEVEL_M,
    VARIATION_SCALES,
    BlockVariation,
    draw_variation,
    synthesize_dance,
)
from dgsdp.metrics.attributes import movement_series
from dgsdp.motion import SMPL24, axis_angle_to_matrix, forward_kinematics, points_y_up_to_z_up

FPS = 60
TINY = {"sequences_per_genre": 2, "seconds": 3.0, "genres": ["PO"], "num_ignored": 0, "sample_rate_hz": 16000}


BEFORE = Path(__file__).resolve().parents[1] / "fixtures" / "synthetic_before_variation" / "dances.npz"


@pytest.mark.parametrize(("genre", "basic"), [("BR", False), ("PO", True), ("JB", False)])
def test_without_variation_a_dance_is_the_one_before_the_option(genre, basic):
    # the fixture was written by the code before the option (commit 412c1be): three 1.5 s dances on beats every
    # 0.5 s from 0.2 s, seed 11; on the machine that wrote it the current code gives the same floats bit for bit
    # (1e-6 allows another CPU's rounding); a dance with the option differs
    expected = np.load(BEFORE)
    beats = np.arange(0.2, 3.0, 0.5)
    poses, trans = synthesize_dance(genre, beats, 90, rng=np.random.default_rng(11), basic=basic)
    np.testing.assert_allclose(poses.astype(np.float32), expected[f"{genre}_poses"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(trans.astype(np.float32), expected[f"{genre}_trans"], rtol=0, atol=1e-6)
    varied, _ = synthesize_dance(
        genre, beats, 90, rng=np.random.default_rng(11), basic=basic, variation_rng=np.random.default_rng(0)
    )
    assert not np.allclose(varied.astype(np.float32), expected[f"{genre}_poses"], atol=1e-3)


def test_draw_variation_ranges():
    rng = np.random.default_rng(0)
    for genre, style in DANCE_STYLES.items():
        v = draw_variation(style, 41, rng)
        assert v.travel_m.shape == v.turn_prob.shape == v.level_m.shape == (6,)  # ceil(41 / 8) blocks
        assert np.all(v.travel_m >= 0) and np.all((v.turn_prob >= 0) & (v.turn_prob <= 0.6))
        assert np.all((v.level_m >= VARIATION_LEVEL_M[0]) & (v.level_m <= VARIATION_LEVEL_M[1]))
        assert v.turn_deg > 0, genre
    many = draw_variation(DANCE_STYLES["PO"], 8 * 400, rng)
    # every scale is drawn, on the spot (0) included, for a genre that neither travels nor turns by default
    assert np.unique(np.round(many.travel_m / many.travel_m.max() * max(VARIATION_SCALES), 6)).size == len(
        VARIATION_SCALES
    )
    assert (many.turn_prob == 0).any() and (many.turn_prob > 0.2).any()


def _block_measures(genre: str, seed: int) -> tuple[BlockVariation, dict[str, np.ndarray], np.ndarray]:
    """One 24 s varied dance at 120 BPM: its drawn variation, its movement series (30 FPS) and each step's block."""
    beats = np.arange(0.25, 24.0, 0.5)
    num_frames = 24 * FPS
    poses, trans = synthesize_dance(
        genre, beats, num_frames, rng=np.random.default_rng(seed), variation_rng=np.random.default_rng(100 + seed)
    )
    # the same draw as synthesize_dance makes (its key count: one key a beat, one before the first frame and two after)
    period = 0.5
    first = beats[0] - period * np.ceil((beats[0] + 1e-9) / period)
    num_keys = len(np.arange(first, num_frames / FPS + 2 * period, period))
    variation = draw_variation(DANCE_STYLES[genre], num_keys, np.random.default_rng(100 + seed))
    rot = axis_angle_to_matrix(torch.from_numpy(poses[::2]).double().reshape(-1, 24, 3))
    joints = points_y_up_to_z_up(forward_kinematics(rot, torch.from_numpy(trans[::2]).double())).numpy()
    series = movement_series(joints, SMPL24, fps=30)
    key = np.searchsorted(first + period * np.arange(num_keys), np.arange(len(joints) - 1) / 30.0, side="right") - 1
    return variation, series, np.clip(key, 0, num_keys - 1) // 8


@pytest.mark.parametrize("genre", ["PO", "JB"])
def test_the_drawn_variation_is_what_the_dance_measures(genre):
    # the measures of the style benchmark (dgsdp.metrics.attributes) follow each block's drawn amounts: more
    # travel per step travels faster, a higher chance of turns turns faster, a lower level stands lower
    drawn = {"travel": [], "turning": [], "level": []}
    measured = {"travel": [], "turning": [], "level": []}
    for seed in range(4):
        variation, series, block = _block_measures(genre, seed)
        for b in range(1, block.max()):  # whole blocks only (away from the dance's ends)
            steps = block == b
            if steps.sum() < 100:
                continue
            drawn["travel"].append(variation.travel_m[b])
            drawn["turning"].append(variation.turn_prob[b])
            drawn["level"].append(variation.level_m[b])
            for name in measured:
                measured[name].append(float(series[name][: len(steps)][steps].mean()))
    for name in drawn:
        r = np.corrcoef(drawn[name], measured[name])[0, 1]
        assert r > 0.6, (name, r, drawn[name], measured[name])
    turning = np.array(measured["turning"])
    still = np.array(drawn["turning"]) == 0
    assert still.any() and (~still).any()
    assert turning[still].max() < 0.05 < turning[~still].max()  # some blocks face ahead, others spin


def test_the_option_changes_the_dances_only_and_has_its_own_folder(tmp_path: Path):
    plain = generate_synthetic_aistpp(tmp_path / "plain", **TINY)
    varied = generate_synthetic_aistpp(tmp_path / "varied", movement_variation=True, **TINY)
    for wav in (plain / "wavs").glob("*.wav"):
        assert (varied / "wavs" / wav.name).read_bytes() == wav.read_bytes()
    motions = sorted(p.name for p in (plain / "motions").glob("*.pkl"))
    assert motions == sorted(p.name for p in (varied / "motions").glob("*.pkl"))
    for name in motions:
        with open(plain / "motions" / name, "rb") as f:  # our own generated files
            a = pickle.load(f)
        with open(varied / "motions" / name, "rb") as f:
            b = pickle.load(f)
        assert a["smpl_poses"].shape == b["smpl_poses"].shape and not np.array_equal(a["smpl_poses"], b["smpl_poses"])
        assert a["smpl_scaling"] == b["smpl_scaling"]
    assert json.loads((varied / MANIFEST).read_text())["settings"]["movement_variation"] is True
    assert outdated_synthetic(plain, movement_variation=True, **TINY)
    assert not outdated_synthetic(varied, movement_variation=True, **TINY)
    # a manifest written before the option: the dances without it
    manifest = json.loads((plain / MANIFEST).read_text())
    del manifest["settings"]["movement_variation"]
    (plain / MANIFEST).write_text(json.dumps(manifest))
    assert not outdated_synthetic(plain, **TINY)
    assert outdated_synthetic(plain, movement_variation=True, **TINY)
    assert synthetic_folder() == "synthetic" and synthetic_folder(True, True) == "synthetic_varied"
    assert synthetic_folder(False, True) == "synthetic_varied_no_offbeats"


def test_command_line_flag(tmp_path: Path):
    main(["--out", str(tmp_path / "cli"), "--sequences-per-genre", "2", "--seconds", "2.5", "--genres", "KR"])
    main(["--out", str(tmp_path / "cli-v"), "--sequences-per-genre", "2", "--seconds", "2.5", "--genres", "KR"]
         + ["--movement-variation"])  # fmt: skip
    assert json.loads((tmp_path / "cli" / MANIFEST).read_text())["settings"]["movement_variation"] is False
    assert json.loads((tmp_path / "cli-v" / MANIFEST).read_text())["settings"]["movement_variation"] is True


def test_a_checkpoint_trained_on_the_varied_data_gets_it_back_in_its_own_folder(tmp_path: Path):
    # evaluate.py on a checkpoint whose synthetic dataset is not here regenerates it from the stored settings
    from types import SimpleNamespace

    from omegaconf import OmegaConf

    from dgsdp.cli.evaluate import _data_location
    from dgsdp.data.synthetic import read_manifest

    stored = {
        "sequences_per_genre": 2,
        "seconds": 2.5,
        "sample_rate_hz": 8000,
        "offbeats": True,
        "num_ignored": 0,
        "movement_variation": True,
    }
    spec = SimpleNamespace(record={"data": {"root": str(tmp_path / "gone"), "synthetic": stored}})
    cfg = OmegaConf.create({"data": {"root": None}, "paths": {"data_dir": str(tmp_path), "cache_dir": "cache"}})
    root, _ = _data_location(cfg, spec)
    assert root == tmp_path / "synthetic_varied"
    assert read_manifest(root)["settings"]["movement_variation"] is True
    assert not (tmp_path / "synthetic").exists()
