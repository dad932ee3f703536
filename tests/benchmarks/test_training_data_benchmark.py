"""benchmarks.training --data: both loaders timed, their batches compared first."""

import re

import pytest
import torch

from dgsdp.benchmarks import training
from dgsdp.data.device import DeviceWindows
from dgsdp.data.synthetic import generate_synthetic_aistpp
from dgsdp.errors import DataError


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    base = tmp_path_factory.mktemp("bench") / "data"
    return generate_synthetic_aistpp(base / "synthetic", seed=0, sequences_per_genre=2, seconds=7.0, num_ignored=0)


def test_times_both_loaders_on_equal_batches(root, capsys):
    training.main(["--device", "cpu", "--data", str(root), "--batch", "4"])
    out = capsys.readouterr().out
    windows = re.search(r"(\d+) training windows", out)
    assert windows and int(windows.group(1)) == 50  # 10 training dances of 7 s: 5 windows each
    times = re.search(r"host loader \(collate \+ copy\) ([\d.]+), on the device ([\d.]+)", out)
    assert times and float(times.group(1)) > 0 and float(times.group(2)) > 0


def test_unequal_batches_and_a_missing_dataset_stop_it(root, tmp_path, monkeypatch):
    with pytest.raises(DataError, match="no dataset there"):
        training.bench_data(str(tmp_path / "none"), torch.device("cpu"), 4)
    batch = DeviceWindows.batch
    monkeypatch.setattr(DeviceWindows, "batch", lambda self, items: {**batch(self, items), "start": torch.zeros(1)})
    with pytest.raises(RuntimeError, match=r"different batches \('start'\)"):
        training.bench_data(str(root), torch.device("cpu"), 4)
