"""Atomic checkpoints: a write that fails half-way leaves the previous file intact and no temporary file; a
Lightning run with AtomicModelCheckpoint writes every checkpoint through the atomic writer."""

from __future__ import annotations

import lightning as L
import pytest
import torch
from torch.utils.data import DataLoader, TensorDataset

from dgsdp.training.checkpoint import AtomicCheckpointIO, AtomicModelCheckpoint


def half_write(checkpoint, f):
    """Writes a few bytes of the file, then fails (as a full disk or a kill would)."""
    f.write(b"partial")
    raise OSError("disk full")


def test_failed_write_keeps_the_previous_checkpoint(tmp_path, monkeypatch):
    import dgsdp.training.checkpoint as checkpoint

    target = tmp_path / "last.ckpt"
    AtomicCheckpointIO().save_checkpoint({"step": torch.tensor(1)}, target)
    assert torch.load(target, weights_only=True)["step"] == 1
    monkeypatch.setattr(checkpoint.torch, "save", half_write)
    with pytest.raises(OSError, match="disk full"):
        AtomicCheckpointIO().save_checkpoint({"step": torch.tensor(2)}, target)
    monkeypatch.undo()
    assert torch.load(target, weights_only=True)["step"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.ckpt"]


class Linear(L.LightningModule):
    def __init__(self) -> None:
        super().__init__()
        self.layer = torch.nn.Linear(2, 1)

    def training_step(self, batch, batch_idx):
        (x,) = batch
        return self.layer(x).pow(2).mean()

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.1)


def test_model_checkpoint_writes_through_the_atomic_writer(tmp_path):
    saved: list[str] = []

    class Recording(AtomicCheckpointIO):
        def save_checkpoint(self, checkpoint, path, storage_options=None):
            saved.append(str(path))
            super().save_checkpoint(checkpoint, path, storage_options)

    callback = AtomicModelCheckpoint(dirpath=tmp_path / "ckpt", every_n_train_steps=2, save_last=True, save_top_k=-1)
    trainer = L.Trainer(
        max_steps=4, accelerator="cpu", callbacks=[callback], logger=False, enable_progress_bar=False,
        enable_model_summary=False, default_root_dir=tmp_path,
    )  # fmt: skip
    trainer.strategy.checkpoint_io = Recording()  # kept as it is: already atomic
    trainer.fit(Linear(), DataLoader(TensorDataset(torch.randn(8, 2)), batch_size=2))
    assert isinstance(trainer.strategy.checkpoint_io, Recording)
    files = sorted(p.name for p in (tmp_path / "ckpt").iterdir())
    assert "last.ckpt" in files and not [f for f in files if f.endswith(".tmp")]
    assert str(tmp_path / "ckpt" / "last.ckpt") in saved and len(saved) >= 3  # step 2, step 4 and last

    plain = L.Trainer(max_steps=1, accelerator="cpu", callbacks=[AtomicModelCheckpoint(dirpath=tmp_path / "b")],
                      logger=False, enable_progress_bar=False, enable_model_summary=False, default_root_dir=tmp_path)  # fmt: skip
    plain.fit(Linear(), DataLoader(TensorDataset(torch.randn(2, 2)), batch_size=2))
    assert isinstance(plain.strategy.checkpoint_io, AtomicCheckpointIO)  # the default writer was replaced
    assert [p.suffix for p in (tmp_path / "b").iterdir()] == [".ckpt"]
