"""data.tempo_augment: training windows played at a random tempo, motion and music features together."""

import numpy as np
import pytest
import torch

from dgsdp.data.datamodule import Sequence, WindowDataset, check_tempo_augment
from dgsdp.errors import ConfigError


class Identity:
    def normalize(self, x):
        return x


def sequence(n=400, seed=0):
    rng = np.random.default_rng(seed)
    motion = rng.random((n, 151)).astype(np.float32)
    motion[:, :4] = rng.random((n, 4)) > 0.5
    audio = rng.random((n, 35)).astype(np.float32)
    audio[:, 33:] = 0
    audio[::6, 33] = 1  # onset peaks every 6 frames
    audio[3::12, 34] = 1  # beats every 12 frames from frame 3
    return Sequence("gBR_sBM_cAll_d04_mBR0_ch01", "BR", 0, "mBR0", motion, audio)


def dataset(rate_range, seq=None):
    return WindowDataset([seq or sequence()], Identity(), length=150, stride=15, tempo_range=rate_range)


def test_rate_one_is_the_plain_window():
    plain, same = dataset(None), dataset((1.0, 1.0))
    for i in range(len(plain)):
        assert torch.equal(plain[i]["motion"], same[i]["motion"]) and torch.equal(plain[i]["audio"], same[i]["audio"])


def test_a_faster_window_resamples_motion_and_keeps_every_beat():
    seq = sequence()
    item = dataset((1.25, 1.25), seq)[1]  # window 1 starts at frame 15
    t = 15 + np.arange(150) * 1.25  # source time of each new frame
    i0 = np.floor(t).astype(int)
    w = (t - i0)[:, None]
    expected = seq.motion[i0] * (1 - w) + seq.motion[i0 + 1] * w  # by hand, linear between the two frames
    assert np.allclose(item["motion"][:, 4:].numpy(), expected[:, 4:], atol=1e-6)
    assert set(np.unique(item["motion"][:, :4].numpy())) <= {0.0, 1.0}  # contacts stay binary
    assert np.allclose(item["audio"][:, :33].numpy(), (seq.audio[i0] * (1 - w) + seq.audio[i0 + 1] * w)[:, :33])
    beats = np.flatnonzero(item["audio"][:, 34].numpy())
    source_beats = np.arange(15, 15 + 149 * 1.25 + 1)[(np.arange(15, 15 + 149 * 1.25 + 1) % 12) == 3]
    assert np.array_equal(beats, np.round((source_beats - 15) / 1.25).astype(int))  # every beat, 9.6 frames apart
    assert item["audio"][:, 33].sum() == len(np.arange(18, 15 + 149 * 1.25 + 1, 6))  # every onset peak too


def test_windows_near_the_end_start_earlier_and_short_sequences_keep_their_tempo():
    data = dataset((1.25, 1.25))
    last = data[len(data) - 1]
    assert last["start"] + 149 * 1.25 <= 399 and last["motion"].shape == (150, 151)
    short = dataset((1.25, 1.25), sequence(n=160))
    assert torch.equal(short[0]["motion"], torch.from_numpy(sequence(n=160).motion[:150]))


def test_rates_are_drawn_in_the_range_from_the_seeded_generator():
    data = dataset((0.8, 1.25))
    torch.manual_seed(0)
    first = [data[0]["audio"] for _ in range(5)]
    torch.manual_seed(0)
    again = [data[0]["audio"] for _ in range(5)]
    assert all(torch.equal(a, b) for a, b in zip(first, again, strict=True))
    assert not all(torch.equal(first[0], a) for a in first[1:])
    spacing = [np.diff(np.flatnonzero(a[:, 34].numpy())).mean() for a in first]
    assert all(12 / 1.25 - 0.5 <= s <= 12 / 0.8 + 0.5 for s in spacing)


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ([1.2, 0.9], "needs 0 < lo <= hi"),
        ([0, 1.2], "needs 0 < lo <= hi"),
        ("fast", "must be two rates"),
        ([0.8], "must be two rates"),
    ],
)
def test_bad_ranges_are_config_errors(value, message):
    with pytest.raises(ConfigError, match=message):
        check_tempo_augment(value, has_features=True)


def test_tempo_augment_needs_frame_rate_features():
    assert check_tempo_augment(None, has_features=False) is None
    assert check_tempo_augment([0.8, 1.25], has_features=True) == (0.8, 1.25)
    with pytest.raises(ConfigError, match="needs an audio encoder that gives features per frame"):
        check_tempo_augment([0.8, 1.25], has_features=False)
