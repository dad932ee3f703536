"""Windows kept on the training device (data.on_device): the host loader's batches, order, shards and resume state,
equal to the last bit, and the same trained weights; under trainer.overfit_batches, the training windows in order."""

from types import SimpleNamespace

import pytest
import torch
from torch.utils.data import SequentialSampler

from dgsdp.audio import LibrosaEncoder
from dgsdp.data.datamodule import DanceDataModule, EpochShuffleSampler, ResumableLoader
from dgsdp.data.device import DeviceLoader, DeviceWindows
from dgsdp.data.synthetic import generate_synthetic_aistpp
from dgsdp.errors import ConfigError
from dgsdp.style.movement import MOVEMENT_CHANNELS


@pytest.fixture(scope="module")
def datamodule(tmp_path_factory):
    base = tmp_path_factory.mktemp("device")
    root = generate_synthetic_aistpp(base / "data", seed=0, sequences_per_genre=2, seconds=7.0, num_ignored=0)
    dm = DanceDataModule(
        str(root), str(base / "cache"), audio_encoder=LibrosaEncoder(), batch_size=4, progress=False,
        movement_channels=MOVEMENT_CHANNELS,
    )  # fmt: skip
    dm.setup("fit")
    return dm


def assert_same_batch(host: dict, device: dict) -> None:
    assert host.keys() == device.keys()
    for key, value in host.items():
        if isinstance(value, torch.Tensor):
            other = device[key]
            assert other.dtype == value.dtype and other.shape == value.shape, key
            assert torch.equal(other, value), key
        else:
            assert device[key] == value, key


def test_batches_equal_the_host_loaders_over_epochs(datamodule):
    dataset = datamodule.datasets["train"]
    host = ResumableLoader(dataset, batch_size=4, seed=7)
    device = DeviceLoader(DeviceWindows(dataset, "cpu"), batch_size=4, sampler=EpochShuffleSampler(len(dataset), 7))
    assert len(host) == len(device) == len(dataset) // 4
    for epoch in range(2):
        host.sampler.set_epoch(epoch)
        device.sampler.set_epoch(epoch)
        pairs = list(zip(host, device, strict=True))
        assert len(pairs) == len(host)
        for a, b in pairs:
            assert {"motion", "audio", "movement", "genre", "start", "name", "music_id"} <= a.keys()
            assert_same_batch(a, b)
    # validation: in order, the last batch partial
    val = datamodule.datasets["val"]
    host_val = list(torch.utils.data.DataLoader(val, batch_size=4, shuffle=False))
    device_val = list(DeviceLoader(DeviceWindows(val, "cpu"), batch_size=4))
    assert len(host_val) == len(device_val)
    for a, b in zip(host_val, device_val, strict=True):
        assert_same_batch(a, b)


def test_a_song_shorter_than_its_dance_holds_its_last_frame(datamodule):
    dataset = datamodule.datasets["train"]
    seq = dataset.sequences[0]
    full = seq.audio
    try:
        seq.audio = full[:160]  # the last window (start 60) runs 50 frames past the song's end
        host = [dataset[i] for i, (s, _) in enumerate(dataset.index) if s == 0]
        windows = DeviceWindows(dataset, "cpu")
        device = windows.batch([i for i, (s, _) in enumerate(dataset.index) if s == 0])
        assert torch.equal(device["audio"], torch.stack([item["audio"] for item in host]))
        assert torch.equal(device["audio"][-1, 100:], device["audio"][-1, 99:100].expand(50, -1))
    finally:
        seq.audio = full


def test_shards_and_resume_follow_the_host_loader(datamodule):
    dataset = datamodule.datasets["train"]
    windows = DeviceWindows(dataset, "cpu")
    for rank in range(2):
        host = ResumableLoader(dataset, batch_size=3, seed=1, rank=rank, world_size=2)
        device = DeviceLoader(
            windows, batch_size=3, sampler=EpochShuffleSampler(len(windows), 1, rank=rank, world_size=2)
        )
        served = []
        for i, batch in enumerate(device):
            served.append(batch["name"])
            if i == 2:
                state = device.state_dict()
                break
        assert state == {"served": 3}
        resumed = DeviceLoader(
            windows, batch_size=3, sampler=EpochShuffleSampler(len(windows), 1, rank=rank, world_size=2)
        )
        resumed.load_state_dict(state)
        rest = [b["name"] for b in resumed]
        assert served + rest == [b["name"] for b in host]


def test_choices_and_refusals(datamodule, tmp_path):
    root, cache = str(datamodule.root), str(datamodule.cache_dir)
    with pytest.raises(ConfigError, match="data.on_device='gpu'"):
        DanceDataModule(root, cache, on_device="gpu")
    auto = DanceDataModule(root, cache, progress=False)  # auto, no trainer: the CPU, so the host loader
    auto.setup("fit")
    assert isinstance(auto.train_dataloader(), ResumableLoader)
    forced = DanceDataModule(root, cache, progress=False, on_device=True)
    forced.setup("fit")
    assert isinstance(forced.train_dataloader(), DeviceLoader)
    stretched = DanceDataModule(
        root, cache, audio_encoder=LibrosaEncoder(), progress=False, on_device="true", tempo_augment=[0.8, 1.25]
    )
    stretched.setup("fit")
    with pytest.raises(ConfigError, match="random tempo"):
        stretched.train_dataloader()
    wave = DanceDataModule(root, cache, waveform_sample_rate=16000, progress=False, on_device="true")
    wave.setup("fit")
    with pytest.raises(ConfigError, match="waveform"):
        wave.train_dataloader()


def test_overfit_batches_serve_the_training_windows_in_order(datamodule):
    """Under trainer.overfit_batches the device loader and the host loader both serve the training windows in their
    stored order through a SequentialSampler (which Lightning leaves as it is), the same batches every epoch."""
    root, cache = str(datamodule.root), str(datamodule.cache_dir)
    trainer = SimpleNamespace(overfit_batches=2, strategy=SimpleNamespace(root_device=torch.device("cpu")))
    epochs = {}
    for on_device in ("true", "false"):
        dm = DanceDataModule(root, cache, batch_size=4, progress=False, on_device=on_device)
        dm.setup("fit")
        dm.trainer = trainer
        loader = dm.train_dataloader()
        assert isinstance(loader, DeviceLoader if on_device == "true" else torch.utils.data.DataLoader)
        assert isinstance(loader.sampler, SequentialSampler)
        epochs[on_device] = [list(loader) for _ in range(2)]
        dataset = dm.datasets["train"]
        stored = [(dataset.sequences[i].name, start) for i, start in dataset.index]
        for batches in epochs[on_device]:
            assert [(n, s) for b in batches for n, s in zip(b["name"], b["start"].tolist(), strict=True)] == stored
    for host, device in zip(epochs["false"][0], epochs["true"][0], strict=True):
        assert_same_batch(host, device)
