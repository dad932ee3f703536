"""Training windows from a generated dataset: counts, normalisation, caching, bad input."""

import numpy as np
import pytest
import torch

from dgsdp.audio import LibrosaEncoder
from dgsdp.data.datamodule import (
    DanceDataModule,
    EpochShuffleSampler,
    ResumableLoader,
    load_sequences,
    window_starts,
)
from dgsdp.data.synthetic import generate_synthetic_aistpp
from dgsdp.errors import AudioError, DataError
from dgsdp.utils.io import DiskCache

SECONDS = 7.0


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds") / "synthetic"
    return generate_synthetic_aistpp(root, seed=0, sequences_per_genre=2, seconds=SECONDS, num_ignored=0)


def test_window_starts_hand_counted():
    assert window_starts(150, 150, 15) == [0]
    assert window_starts(149, 150, 15) == []
    assert window_starts(210, 150, 15) == [0, 15, 30, 45, 60]
    assert len(window_starts(300, 150, 75)) == 3


def test_window_counts_follow_length_stride_and_clip_lengths(dataset, tmp_path):
    dm = DanceDataModule(str(dataset), str(tmp_path / "cache"), batch_size=4, progress=False)
    dm.prepare_data()
    dm.setup("fit")
    train = dm.sequences("train")
    n_frames = int(SECONDS * 30)  # 60 FPS pickles taken every second frame
    assert all(len(s.motion) == n_frames for s in train)
    per_clip = (n_frames - 150) // 15 + 1  # 5 s windows, 0.5 s stride
    assert len(dm.datasets["train"]) == len(train) * per_clip
    per_test_clip = (n_frames - 150) // 75 + 1  # 2.5 s stride for evaluation
    assert len(dm.datasets["val"]) == len(dm.sequences("val")) * per_test_clip
    item = dm.datasets["train"][0]
    assert item["motion"].shape == (150, 151)
    assert item["motion"].min() >= -1 and item["motion"].max() <= 1
    assert isinstance(item["genre"], int) and item["music_id"].startswith("m")
    # the normaliser was fitted on every frame of the training sequences
    all_frames = torch.from_numpy(np.concatenate([s.motion for s in train]))
    assert torch.allclose(dm.normalizer.data_min, all_frames.min(0).values)
    assert torch.allclose(dm.normalizer.data_max, all_frames.max(0).values)


def test_audio_features_and_waveform_windows(dataset, tmp_path):
    dm = DanceDataModule(
        str(dataset), str(tmp_path / "cache"), audio_encoder=LibrosaEncoder(), batch_size=4, progress=False
    )
    dm.setup("fit")
    item = dm.datasets["train"][3]
    assert item["audio"].shape == (150, 35)
    seq = dm.sequences("train")[0]
    start = dm.datasets["train"].index[3][1]
    assert torch.equal(item["audio"], torch.from_numpy(seq.audio[start : start + 150]).float())
    wave = DanceDataModule(str(dataset), str(tmp_path / "cache"), waveform_sample_rate=16000, progress=False)
    wave.setup("fit")
    assert wave.datasets["train"][0]["audio"].shape == (5 * 16000,)


def test_processed_motion_is_cached_and_keyed_by_content(dataset, tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    load_sequences(dataset, "test", cache_dir=cache, progress=False)
    calls = []
    import dgsdp.data.datamodule as dmod

    original = dmod.process_motion
    monkeypatch.setattr(dmod, "process_motion", lambda *a, **k: calls.append(1) or original(*a, **k))
    load_sequences(dataset, "test", cache_dir=cache, progress=False)
    assert calls == []  # second read: no processing
    load_sequences(dataset, "test", cache_dir=cache, fps=20, progress=False)  # another setting misses
    assert len(calls) == 10


def test_killed_caching_leaves_nothing_used(dataset, tmp_path, monkeypatch):
    cache = tmp_path / "cache"

    def die(*args, **kwargs):
        raise KeyboardInterrupt  # as if the process were stopped in the middle of writing

    monkeypatch.setattr(np, "savez", die)
    with pytest.raises(KeyboardInterrupt):
        load_sequences(dataset, "test", cache_dir=cache, progress=False)
    monkeypatch.undo()
    leftovers = [p for p in cache.rglob("*") if p.is_file()]
    assert leftovers == []  # no partial entry that a later run could read
    seqs = load_sequences(dataset, "test", cache_dir=cache, progress=False)
    assert len(seqs) == 10 and len(list(cache.rglob("*.npz"))) == 10


def test_corrupt_cache_entry_is_recomputed(tmp_path):
    cache = DiskCache(tmp_path, "ns")
    cache.path("k").parent.mkdir(parents=True)
    cache.path("k").write_bytes(b"truncated")
    out = cache.get_or_compute("k", lambda: {"a": np.arange(3)})
    assert cache.misses == 1 and out["a"].tolist() == [0, 1, 2]


def test_empty_and_unreadable_wav(dataset, tmp_path):
    import shutil

    root = tmp_path / "copy"
    shutil.copytree(dataset, root)
    wav = sorted((root / "wavs").glob("*.wav"))[0]
    music_id = wav.stem
    wav.write_bytes(b"")
    with pytest.raises(AudioError, match=music_id):
        load_sequences(root, "train", cache_dir=tmp_path / "c1", audio_encoder=LibrosaEncoder(), progress=False)
    wav.write_bytes(b"RIFF garbage that is not audio")
    with pytest.raises(AudioError, match=music_id):
        load_sequences(root, "train", cache_dir=tmp_path / "c2", audio_encoder=LibrosaEncoder(), progress=False)


def test_missing_dataset_and_unknown_split(dataset, tmp_path):
    dm = DanceDataModule(str(tmp_path / "none"), str(tmp_path / "cache"), progress=False)
    with pytest.raises(DataError, match="no AIST\\+\\+ dataset"):
        dm.prepare_data()
    with pytest.raises(DataError, match="unknown split 'valid'"):
        load_sequences(dataset, "valid", cache_dir=tmp_path)


def test_shuffle_depends_only_on_seed_and_epoch():
    a, b = EpochShuffleSampler(20, seed=3), EpochShuffleSampler(20, seed=3)
    a.set_epoch(2)
    b.set_epoch(2)
    assert list(a) == list(b) and sorted(a) == list(range(20))
    b.set_epoch(3)
    assert list(a) != list(b)


@pytest.mark.parametrize(("length", "world"), [(20, 2), (23, 3), (7, 4)])
def test_shards_are_disjoint_and_cover_the_permutation(length, world):
    samplers = [EpochShuffleSampler(length, seed=1, rank=r, world_size=world) for r in range(world)]
    for s in samplers:
        s.set_epoch(5)
    shards = [list(s) for s in samplers]
    per_rank = length // world
    assert all(len(shard) == len(s) == per_rank for shard, s in zip(shards, samplers, strict=True))
    union = [i for shard in shards for i in shard]
    assert len(set(union)) == len(union) == world * per_rank  # disjoint
    # the union is the first world * per_rank items of the one permutation every rank draws
    g = torch.Generator().manual_seed(1 * 100_003 + 5)
    assert set(union) == set(torch.randperm(length, generator=g)[: world * per_rank].tolist())


def test_loader_skips_served_batches_on_every_rank():
    data = list(range(40))
    loaders = [ResumableLoader(data, batch_size=3, seed=0, rank=r, world_size=2) for r in range(2)]
    full = [[b.tolist() for b in loader] for loader in loaders]
    assert [len(f) for f in full] == [6, 6]  # 20 items per rank: 6 full batches, the partial one dropped
    for loader, batches in zip(loaders, full, strict=True):
        it = iter(loader)
        next(it), next(it)
        state = loader.state_dict()
        assert state == {"served": 2}
        resumed = ResumableLoader(data, batch_size=3, seed=0, rank=loader.sampler.rank, world_size=2)
        resumed.load_state_dict(state)
        assert [b.tolist() for b in resumed] == batches[2:]
        assert [b.tolist() for b in resumed] == batches  # the next epoch pass starts from the beginning again


def test_sampler_reads_rank_and_world_from_torch_distributed(monkeypatch):
    monkeypatch.setattr(torch.distributed, "is_initialized", lambda: True)
    monkeypatch.setattr(torch.distributed, "get_rank", lambda: 1)
    monkeypatch.setattr(torch.distributed, "get_world_size", lambda: 4)
    s = EpochShuffleSampler(10, seed=0)
    assert (s.rank, s.world_size, len(s)) == (1, 4, 2)
    with pytest.raises(DataError, match="cannot be shared by 4 processes"):
        EpochShuffleSampler(3, seed=0)


def test_loader_refuses_lightnings_distributed_sampler():
    from dgsdp.errors import ConfigError

    with pytest.raises(ConfigError, match="use_distributed_sampler=false"):
        ResumableLoader(list(range(10)), batch_size=2, seed=0, sampler=list(range(10)))
