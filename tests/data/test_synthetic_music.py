"""The synthetic music is mastered over a realistic range: loudness, limiting and clipping, brightness."""

from __future__ import annotations

import numpy as np
import pyloudnorm
import pytest

from dgsdp.data.synthetic_music import (
    DYNAMICS,
    LOUDNESS_RANGE_LUFS,
    Mastering,
    draw_mastering,
    master,
    synthesize_music,
)

SR = 22050


def lufs(y: np.ndarray) -> float:
    return float(pyloudnorm.Meter(SR).integrated_loudness(y.astype(np.float64)))


def test_generated_songs_spread_over_the_loudness_range():
    # 12 songs of 4 s with their own drawn mastering, measured with pyloudnorm directly.
    loudness, clipped = [], []
    for seed in range(12):
        genre = ("BR", "HO", "KR", "JB")[seed % 4]
        y, _ = synthesize_music(genre, 110.0, 4.0, first_beat_s=0.2, sample_rate_hz=SR, rng=np.random.default_rng(seed))
        assert y.dtype == np.float32 and np.abs(y).max() <= 1.0
        loudness.append(lufs(y))
        clipped.append(np.mean(np.abs(y) >= 0.999 * np.abs(y).max()))
    loudness = np.array(loudness)
    low, high = LOUDNESS_RANGE_LUFS
    assert loudness.min() > low - 1.5 and loudness.max() < high + 0.5, loudness
    assert loudness.max() - loudness.min() > 12.0, loudness  # quiet and loud songs alike
    assert max(clipped) > 0.01, clipped  # some songs are flattened against their peak (limited or clipped)


@pytest.mark.parametrize("target", [-30.0, -18.0, -8.0])
def test_master_sets_the_loudness_of_clean_songs(target):
    rng = np.random.default_rng(0)
    t = np.arange(3 * SR) / SR
    drums = np.sin(2 * np.pi * 60 * t) * np.exp(-(t % 0.5) / 0.1) * 0.9
    m = Mastering(loudness_lufs=target, dynamics="clean", drive_db=0.0, tilt_db=0.0, noise=0.01, sustain=0.0)
    y = master(drums, SR, m, rng)
    if np.abs(y).max() < 1.0:  # nothing needed clipping: the target is met exactly
        assert lufs(y) == pytest.approx(target, abs=0.2)
    else:
        assert lufs(y) <= target + 0.2


def test_clipped_and_limited_masters_are_flattened():
    t = np.arange(3 * SR) / SR
    drums = np.sin(2 * np.pi * 60 * t) * np.exp(-(t % 0.5) / 0.1) * 0.9
    flat = {}
    for dynamics in DYNAMICS:
        m = Mastering(loudness_lufs=-24.0, dynamics=dynamics, drive_db=12.0, tilt_db=0.0, noise=0.001, sustain=0.0)
        y = master(drums, SR, m, np.random.default_rng(0))
        assert np.abs(y).max() < 1.0  # quiet enough that the final clip to full scale does nothing
        flat[dynamics] = np.mean(np.abs(y) >= 0.99 * np.abs(y).max())
    assert flat["clipped"] > 0.1 and flat["clean"] < 0.01 and flat["limited"] > flat["clean"], flat


def test_drawn_mastering_covers_every_kind():
    rng = np.random.default_rng(1)
    draws = [draw_mastering(rng) for _ in range(300)]
    assert {d.dynamics for d in draws} == set(DYNAMICS)
    loudness = np.array([d.loudness_lufs for d in draws])
    assert loudness.min() < LOUDNESS_RANGE_LUFS[0] + 2 and loudness.max() > LOUDNESS_RANGE_LUFS[1] - 2
    tilts = np.array([d.tilt_db for d in draws])
    assert tilts.min() < -9 and tilts.max() > 6  # darker and brighter songs
    assert 0.2 < np.mean([d.sustain > 0 for d in draws]) < 0.8
    assert len({d.transpose for d in draws}) >= 10  # keys over (almost) every pitch class
