"""model.speed_conditioning: each training window's mean joint speed, measured by hand here, travels as one more style
channel; a run records its genres' speeds; generation asks a genre for its median speed, free text for what its
words ask, and reports it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from test_train import run

from dgsdp.data.datamodule import Sequence, WindowDataset, add_movement, movement_statistics
from dgsdp.metrics.speed import SPEED_QUANTILES, frame_speeds
from dgsdp.model import DanceDenoiser
from dgsdp.motion import SMPL24, MinMaxNormalizer, pack_pose, pose_to_joints


def gliding(steps_m: list[float]) -> np.ndarray:
    """A standing body gliding along x, every joint moving ``steps_m[k]`` metres from frame k to k + 1."""
    n = len(steps_m) + 1
    trans = torch.zeros(n, 3, dtype=torch.float64)
    trans[1:, 0] = torch.cumsum(torch.tensor(steps_m, dtype=torch.float64), 0)
    trans[:, 2] = 0.9
    rotmats = torch.eye(3, dtype=torch.float64).expand(n, 24, 3, 3)
    return pack_pose(torch.ones(n, 4, dtype=torch.float64), trans, rotmats).float().numpy()


def test_window_speeds_and_their_quantiles_by_hand():
    """A body gliding 1 cm a frame moves 0.3 m/s at 30 FPS; a window of a dance that glides 1 cm then 3 cm a frame
    averages its own frames; a tempo-stretched window is that much faster; the quantiles are numpy's."""
    slow, fast, both = gliding([0.01] * 59), gliding([0.03] * 59), gliding([0.01] * 59 + [0.03] * 60)
    seqs = [Sequence("a", "BR", 0, "mBR0", slow, None), Sequence("b", "BR", 0, "mBR0", both, None),
            Sequence("c", "PO", 1, "mPO0", fast, None)]  # fmt: skip
    add_movement(seqs, SMPL24, 30, ("speed",))
    speeds = [s.movement["speed"] for s in seqs]
    assert np.allclose(speeds[0], 0.3, atol=1e-5) and np.allclose(speeds[2], 0.9, atol=1e-5)
    np.testing.assert_allclose(speeds[1], [0.3] * 59 + [0.9] * 60, atol=1e-4)
    normalizer = MinMaxNormalizer(151)
    normalizer.fit(torch.from_numpy(np.concatenate([s.motion for s in seqs])))
    ds = WindowDataset(seqs, normalizer, length=30, stride=15)
    item = ds[ds.index.index((1, 45))]  # frames 45-74 of b: steps 45-73, 14 at 0.3 m/s and 15 at 0.9
    assert item["movement"].shape == (1,)
    assert float(item["movement"][0]) == pytest.approx((14 * 0.3 + 15 * 0.9) / 29, abs=1e-4)
    assert ds.window_movement(seqs[0], 0, rate=1.5)[0] == pytest.approx(0.45, abs=1e-5)  # played 1.5x faster
    (quantiles,), (median,), (spread,) = movement_statistics(ds, n_genres=3)
    br = sorted(ds.window_movement(seqs[i], s)[0] for i, s in ds.index if seqs[i].genre_index == 0)
    np.testing.assert_allclose(quantiles[0], np.quantile(br, np.linspace(0, 1, SPEED_QUANTILES)), rtol=1e-6)
    np.testing.assert_allclose(quantiles[1], 0.9, atol=1e-5)
    assert np.isnan(quantiles[2]).all()  # no windows of genre 2
    every = [ds.window_movement(seqs[i], s)[0] for i, s in ds.index]
    assert median == pytest.approx(float(np.median(every)))
    assert spread == pytest.approx(float(np.quantile(every, 0.9) - np.quantile(every, 0.1)))
    joints = pose_to_joints(torch.from_numpy(fast))
    np.testing.assert_allclose(frame_speeds(joints.numpy()), 0.9, atol=1e-5)


def test_the_denoiser_takes_the_speed_as_one_more_style_channel():
    kw = dict(d_model=16, n_layers=1, n_heads=2, ff_dim=16, music_encoder_layers=1, audio_dim=5, seq_len=8,
              style_dim=3, dropout=0.0)  # fmt: skip
    torch.manual_seed(0)
    model = DanceDenoiser(speed_conditioning=True, **kw).eval()
    assert model.null_style.shape == (4,) and model.modulations[0].style_dim == 4
    x, t, music = torch.randn(2, 8, 151), torch.tensor([3, 7]), torch.randn(2, 8, 5)
    style = torch.randn(2, 3)
    slow, fast = (torch.cat([style, torch.full((2, 1), v)], -1) for v in (-1.0, 1.0))
    out_slow, out_fast = model(x, t, music, slow), model(x, t, music, fast)
    assert not torch.allclose(out_slow, out_fast)  # the channel reaches the prediction
    with pytest.raises(ValueError, match="4 channels .*3 style channels and the speed channel"):
        model(x, t, music, style)
    keep = torch.tensor([False, False])  # a dropped style drops its speed with it: the learnt null
    assert torch.allclose(model(x, t, music, slow, keep_style=keep), model(x, t, music, fast, keep_style=keep))
    with pytest.raises(ValueError, match="need a model with style"):
        DanceDenoiser(speed_conditioning=True, **{**kw, "style_dim": 0})


def test_a_run_records_its_speeds_and_generation_asks_for_them(tmp_path, tiny_synthetic):
    from dgsdp.generation import DanceGenerator
    from dgsdp.trained import load_model

    _, result = run(tmp_path, tiny_synthetic, "style=onehot", "model.speed_conditioning=true",
                    "trainer.max_steps=2", "trainer.limit_val_batches=0")  # fmt: skip
    model = load_model(result["checkpoint"])
    assert model.speed_conditioning and model.speed_quantiles.shape == (10, SPEED_QUANTILES)
    quantiles, reference = model.speed_quantiles, float(model.speed_reference)
    assert torch.isfinite(quantiles).all() and (quantiles[:, 1:] >= quantiles[:, :-1]).all() and reference > 0
    # the quantile at 0.45 lies halfway between the recorded 0.4 and 0.5
    genre = torch.tensor([3])
    assert float(model.genre_speed(genre, 0.45)) == pytest.approx(float(quantiles[3, 4:6].mean()), rel=1e-5)
    doubled = model.movement_encoding(torch.tensor([[2 * reference]]))  # log2 of twice the median
    assert doubled.shape == (1, 1) and float(doubled[0, 0]) == pytest.approx(1.0)
    gen = DanceGenerator(model, cache_dir=tiny_synthetic["cache"])
    vector, reading = gen.read_style("krump")
    kr = gen.embedder().vocab.index("krump")
    assert vector.shape == (11,) and reading.speed_m_s == pytest.approx(float(quantiles[kr, 5]))
    assert float(vector[-1]) == pytest.approx(math.log2(float(quantiles[kr, 5]) / reference), abs=1e-5)
    assert torch.equal(vector[:10], torch.nn.functional.one_hot(torch.tensor(kr), 10).float())
    assert "the genre Krump, at" in reading.describe()
    styles = model.style_for(torch.tensor([kr, 0]), random=False)  # evaluation and callbacks: the genres' medians
    assert styles.shape == (2, 11) and float(styles[0, -1]) == pytest.approx(float(vector[-1]), abs=1e-5)


def test_a_speed_run_stored_before_movement_channels_loads_as_it_did(tmp_path, tiny_synthetic):
    """Checkpoints of speed-conditioned runs made before model.movement_channels existed have no such key: they load
    with the speed channel alone, their speed buffers, the same style vectors, and resume under today's config."""
    from dgsdp.trained import load_model
    from dgsdp.trained.spec import RunSpec

    cfg, result = run(tmp_path, tiny_synthetic, "style=onehot", "model.speed_conditioning=true",
                      "trainer.max_steps=1", "trainer.limit_val_batches=0")  # fmt: skip
    ckpt = torch.load(result["checkpoint"], map_location="cpu", weights_only=True)
    assert ckpt["hyper_parameters"]["model"].pop("movement_channels") == []
    assert not [k for k in ckpt["state_dict"] if k.endswith(("_spread", "level_quantiles"))]
    old = tmp_path / "before.ckpt"
    torch.save(ckpt, old)
    model, today = load_model(old), load_model(result["checkpoint"])
    assert model.movement_channels == ("speed",) and model.speed_conditioning
    assert torch.equal(model.speed_quantiles, today.speed_quantiles)
    genres = torch.arange(10)
    assert torch.equal(model.style_for(genres, random=False), today.style_for(genres, random=False))
    RunSpec.from_checkpoint(ckpt, str(old)).check_resumable_with(RunSpec.from_checkpoint(
        torch.load(result["checkpoint"], map_location="cpu", weights_only=True), "today"), str(old))  # fmt: skip
